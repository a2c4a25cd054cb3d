"""The training loop of ``semmap train``: weighted cross entropy with median-frequency weights, SGD with the poly
learning rate (rgbd-semantic-mapping-multiscale-crf eq. 6, power 0.9), augmentation, periodic validation mIoU,
checkpoints that ``--resume`` continues from exactly, the best checkpoint by validation mIoU, and a CSV/JSON
log with a loss / mIoU curve.

Every random choice of iteration ``i`` (which images, how they are augmented, dropout) is drawn from generators
seeded by ``(seed, i)``, so a run resumed from a checkpoint continues bit for bit as if never interrupted.

Run folder: ``config.json``, ``class_weights.json``, ``log.csv``, ``log.json``, ``curve.png``, ``last.pt``
(checkpoint), ``best.pt`` and ``final.pt`` (network weight files for ``--weights``).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812  (the usual PyTorch alias)

from semmap.errors import ConfigError, DatasetError, FormatError
from semmap.eval.semantic import confusion, scores
from semmap.files.atomic import write_bytes_atomic, write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.limits import check, check_network_input
from semmap.perception.network import IMAGENET_MEAN, IMAGENET_STD
from semmap.perception.networks.pretrained import LoadSummary, init_plan, load_pretrained
from semmap.perception.networks.pspnet import AUX_WEIGHT
from semmap.perception.networks.registry import (
    MODELS,
    NetworkSpec,
    build_network,
    count_parameters,
    read_torch_file,
    save_weights,
)
from semmap.perception.networks.resnet import LAYOUTS
from semmap.train.augment import Augmentation, augment
from semmap.train.calibrate import calibration_scores, fit_temperature, softmax
from semmap.train.class_weights import IGNORE, median_frequency_weights
from semmap.train.data import DEPTH_MM, TrainingSet, gather

log = logging.getLogger("semmap")

CHECKPOINT_FORMAT = "semmap-train-checkpoint"
#: The RGB-D paper's fusion-module dilation (12) belongs to 480-pixel-wide inputs; smaller inputs scale it.
PAPER_INPUT_WIDTH = 480
#: Settings that must match to resume a run.
#: Validation pixels the temperature is fitted on: every n-th row and column of each image.
CALIBRATION_PIXEL_STEP = 8
RESUME_KEYS = ("model", "width", "depth", "backbone", "msff_dilation", "input_size", "batch", "lr", "momentum",
               "weight_decay", "poly_power", "seed", "augment", "sensor_augment", "class_weighting", "iterations_total",
               "init")


@dataclass(frozen=True)
class TrainSettings:
    """One training run; ``epochs`` passes over the training images unless ``iterations`` is given."""

    model: str
    data: tuple[Path, ...]
    out: Path
    val: tuple[Path, ...] = ()
    epochs: float = 12.0
    iterations: int | None = None
    batch: int = 8
    lr: float = 0.01
    momentum: float = 0.9
    weight_decay: float = 1e-4
    poly_power: float = 0.9
    input_size: tuple[int, int] = (160, 120)
    width: float = 0.25
    depth: int = 18
    backbone: str = "resnet"
    msff_dilation: int | None = None
    device: str = "cpu"
    seed: int = 0
    threads: int | None = None
    eval_every: int = 100
    checkpoint_every: int | None = None
    val_fraction: float = 0.1
    class_map: Path | None = None
    label_set: Path | None = None
    depth_scale: float | None = None
    augment: bool = True
    sensor_augment: bool = False  #: real-sensor-like augmentation (:meth:`Augmentation.sensor`)
    class_weighting: bool = True
    init: str | None = None  #: pretrained start (``--init``, :mod:`~semmap.perception.networks.pretrained`)

    def __post_init__(self) -> None:
        if not self.data:
            raise ConfigError("training needs at least one data folder (--data)")
        if min(self.input_size) < 16:
            raise ConfigError(f"training input must be at least 16x16, got {self.input_size}")
        if self.device not in ("cpu", "cuda") and not self.device.startswith("cuda:"):
            raise ConfigError(f"--device must be cpu or cuda, got {self.device!r}")
        check("batch", self.batch)
        check("iterations", self.iterations)
        check("epochs", self.epochs)
        check("depth_scale", self.depth_scale)
        check("learning_rate", self.lr, "--lr")
        check("width", self.width, "--width")
        check("threads", self.threads)
        check("every_positive", self.eval_every, "--eval-every")
        check("seed", self.seed)
        if self.depth not in LAYOUTS:
            raise ConfigError(f"--resnet-depth must be one of {' | '.join(map(str, sorted(LAYOUTS)))}, "
                              f"got {self.depth}")
        if self.device == "cpu":  # one step's activations and gradients, in this machine's memory
            check_network_input(*self.input_size, self.batch, training=True)
        if self.init is not None:
            init_plan(self.init)

    def with_init(self) -> TrainSettings:
        """These settings with the backbone (and, for torchvision, depth and full width) ``--init`` needs."""
        if self.init is None:
            return self
        plan = init_plan(self.init)
        entry = MODELS[self.model]
        fits = {"resnet": entry.chooses_backbone or entry.backbone is None,
                "vgg16": entry.chooses_backbone or entry.backbone == "vgg16"}.get(plan.backbone, True)
        if not fits:
            raise ConfigError(f"--init {self.init}: --model {self.model} has no {plan.backbone} backbone")
        if plan.model is not None and plan.model != self.model:
            raise ConfigError(f"--init {self.init}: holds a {plan.model} network, not --model {self.model}")
        defaults = TrainSettings.__dataclass_fields__
        for option, name, wanted in (("--backbone", "backbone", plan.backbone), ("--resnet-depth", "depth", plan.depth),
                                     ("--width", "width", plan.width)):
            given = getattr(self, name)
            if wanted is not None and given != defaults[name].default and given != wanted:
                raise ConfigError(f"{option} {given} conflicts with --init {self.init}, which sets {option} {wanted}; "
                                  f"leave {option} out")
        return replace(self, backbone=plan.backbone, depth=plan.depth or self.depth, width=plan.width or self.width,
                       msff_dilation=plan.msff_dilation if plan.model is not None else self.msff_dilation)

    def spec(self, num_classes: int) -> NetworkSpec:
        dil = self.msff_dilation or max(1, round(12 * self.input_size[0] / PAPER_INPUT_WIDTH))
        return NetworkSpec(self.model, num_classes, width=self.width, depth=self.depth, backbone=self.backbone,
                           msff_dilation=dil)

    def to_dict(self) -> dict:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, Path):
                d[k] = str(v)
            elif isinstance(v, tuple) and v and isinstance(v[0], Path):
                d[k] = [str(p) for p in v]
        d["input_size"] = list(self.input_size)
        return d


@dataclass
class TrainResult:
    """What a run produced: weight files, the best validation scores, the log rows."""

    out: Path
    best: Path | None
    final: Path
    best_miou: float
    iterations: int
    rows: list[dict] = field(default_factory=list)


Progress = Callable[[int, int, dict], None]


def poly_lr(base: float, iteration: int, total: int, power: float) -> float:
    """lr = base (1 - iter / max_iter)^power (eq. 6)."""
    return base * (1.0 - iteration / total) ** power


def seeded(seed: int, iteration: int, stream: int) -> torch.Generator:
    """The generator of random stream ``stream`` of iteration ``iteration``: the same draws whenever it runs."""
    return torch.Generator().manual_seed(seed_of(seed, iteration, stream))


def seed_of(seed: int, iteration: int, stream: int) -> int:
    """An integer seed for stream ``stream`` of iteration ``iteration`` (torch.manual_seed for dropout)."""
    return int(np.random.SeedSequence([seed, iteration, stream]).generate_state(1)[0])


def batch_tensors(ds: TrainingSet, idx: np.ndarray, uses_depth: bool
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Images ``idx`` of ``ds`` as tensors: rgb (N, 3, H, W) in [0, 1], labels (N, H, W) int64, depth
    (N, 1, H, W) metres (None unless ``uses_depth``)."""
    rgb = torch.from_numpy(ds.rgb[idx]).permute(0, 3, 1, 2).float().div_(255.0)
    labels = torch.from_numpy(ds.labels[idx].astype(np.int64))
    depth = None
    if uses_depth:
        depth = torch.from_numpy(ds.depth[idx].astype(np.float32) / DEPTH_MM)[:, None]
    return rgb, labels, depth


def normalise(rgb: torch.Tensor) -> torch.Tensor:
    """RGB in [0, 1] normalised per channel as the segmenter feeds the network (ImageNet mean and deviation)."""
    mean = torch.tensor(IMAGENET_MEAN, dtype=rgb.dtype, device=rgb.device).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD, dtype=rgb.dtype, device=rgb.device).view(1, 3, 1, 1)
    return (rgb - mean) / std


def refuse_other_settings(path: Path, saved: dict, now: dict, keys: Iterable[str]) -> None:
    """A ConfigError naming each of ``keys`` whose value in a checkpoint's ``saved`` settings differs from ``now``
    (a run resumes only as it started)."""
    diff = [k for k in keys if saved.get(k) != now.get(k)]
    if diff:
        raise ConfigError(f"{path}: cannot resume with different settings: "
                          + ", ".join(f"{k} {saved.get(k)!r} -> {now.get(k)!r}" for k in diff))


def batch_indices(seed: int, iteration: int, batch: int, n: int) -> np.ndarray:
    """Images of iteration ``iteration``: consecutive slices of a fresh permutation per epoch."""
    pos = np.arange(iteration * batch, (iteration + 1) * batch)
    out = np.empty(batch, np.int64)
    for epoch in np.unique(pos // n):
        perm = torch.randperm(n, generator=seeded(seed, int(epoch), 1)).numpy()
        sel = pos // n == epoch
        out[sel] = perm[pos[sel] % n]
    return out


class Trainer:
    """Holds the data, network and optimiser of one run; :meth:`run` trains to the end or ``stop_after``."""

    def __init__(self, settings: TrainSettings, *, resume: bool = False) -> None:
        settings = settings.with_init()
        self.s = settings
        check_outputs([("--out", settings.out, OutputKind.FOLDER)],
                      [*(("--data", d) for d in settings.data), *(("--val", v) for v in settings.val),
                       ("--class-map", settings.class_map), ("--labelset", settings.label_set)])
        if settings.threads is not None:
            torch.set_num_threads(int(settings.threads))
        self.device = self._device(settings.device)
        need_depth = MODELS[settings.model].uses_depth
        label_set = None
        if settings.label_set is not None:
            from semmap.types import LabelSet

            label_set = LabelSet.load(settings.label_set)
        load = dict(class_map_path=settings.class_map, depth_scale=settings.depth_scale, need_depth=need_depth)
        self.train_set = gather(list(settings.data), settings.input_size, label_set=label_set, **load)
        if settings.val:
            self.val_set = gather(list(settings.val), settings.input_size, label_set=self.train_set.label_set,
                                  **load)
        else:
            self.train_set, self.val_set = _split(self.train_set, settings.val_fraction)
        self.label_set = self.train_set.label_set
        k = len(self.label_set)
        self.spec = settings.spec(k)
        weights = (median_frequency_weights(self.train_set.labels, k) if settings.class_weighting
                   else (np.arange(k) != IGNORE).astype(np.float32))
        self.class_weights = weights
        torch.manual_seed(int(np.random.SeedSequence([settings.seed, 0, 4]).generate_state(1)[0]))  # initial weights
        self.model = build_network(self.spec)
        #: what ``--init`` loaded (None: trained from scratch, or resumed from a checkpoint)
        self.init_summary: LoadSummary | None = None
        if settings.init is not None and not resume:
            self.init_summary = load_pretrained(self.model, settings.init)
            log.info("%s", self.init_summary.text())
        self.model = self.model.to(self.device)
        self.optimizer = torch.optim.SGD(self.model.parameters(), lr=settings.lr, momentum=settings.momentum,
                                         weight_decay=settings.weight_decay)
        n = len(self.train_set)
        self.total = settings.iterations or max(1, math.ceil(settings.epochs * n / settings.batch))
        self.iteration = 0
        self.best_miou = -1.0
        self.rows: list[dict] = []
        self.elapsed = 0.0
        out = settings.out
        self.last_path, self.best_path, self.final_path = out / "last.pt", out / "best.pt", out / "final.pt"
        if resume:
            self._load_checkpoint()
        elif self.last_path.exists():
            raise ConfigError(f"{out}: holds a training run already (last.pt); continue it with --resume or "
                              f"choose another --out")
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "config.json", json.dumps(self._config(), indent=2))
        write_text_atomic(out / "class_weights.json", json.dumps(
            {name: round(float(w), 4) for name, w in zip(self.label_set.names, weights, strict=True)}, indent=1))

    # ------------------------------------------------------------------ setup
    @staticmethod
    def _device(name: str) -> torch.device:
        if name.startswith("cuda") and not torch.cuda.is_available():
            raise ConfigError("--device cuda: no CUDA GPU is available to this PyTorch")
        return torch.device(name)

    def _config(self) -> dict:
        return {**self.s.to_dict(), "iterations_total": self.total, "spec": self.spec.to_dict(),
                "network": self.spec.describe(), "parameters": count_parameters(self.model),
                "train_images": len(self.train_set), "val_images": len(self.val_set),
                "label_set": self.label_set.to_dict()}

    # ------------------------------------------------------------------ one step
    def _batch(self, ds: TrainingSet, idx: np.ndarray):
        return batch_tensors(ds, idx, self.spec.uses_depth)

    def step(self) -> float:
        """One SGD step of iteration ``self.iteration``; returns its loss."""
        s, it = self.s, self.iteration
        idx = batch_indices(s.seed, it, s.batch, len(self.train_set))
        rgb, labels, depth = self._batch(self.train_set, idx)
        aug = Augmentation.sensor() if s.sensor_augment else Augmentation()
        rgb, labels, depth = augment(rgb, labels, depth, replace(aug, enabled=s.augment), seeded(s.seed, it, 2))
        torch.manual_seed(seed_of(s.seed, it, 3))  # dropout
        dev = self.device
        x = normalise(rgb.to(dev))
        y = labels.to(dev)
        d = None if depth is None else depth.to(dev)
        for group in self.optimizer.param_groups:
            group["lr"] = poly_lr(s.lr, it, self.total, s.poly_power)
        self.model.train()
        logits, aux = self.model.forward_train(x, d)
        w = torch.from_numpy(self.class_weights).to(dev)
        loss = F.cross_entropy(logits, y, weight=w, ignore_index=IGNORE)
        if aux is not None:
            loss = loss + AUX_WEIGHT * F.cross_entropy(aux, y, weight=w, ignore_index=IGNORE)
        if not torch.isfinite(loss):
            # a batch whose pixels are all ignored gives NaN; anything else is divergence
            if int((y != IGNORE).sum()) == 0:
                self.iteration += 1
                return 0.0
            raise ConfigError(f"training diverged at iteration {it} (loss {float(loss)}); lower --lr")
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.iteration += 1
        return float(loss.detach())

    @torch.no_grad()
    def evaluate(self, batch: int = 8) -> dict:
        """mIoU, MPA (eqs. 11-12) and pixel accuracy on the validation images at the training size."""
        self.model.eval()
        k = len(self.label_set)
        conf = np.zeros((k, k), np.int64)
        sample_logits, sample_labels = [], []
        for start in range(0, len(self.val_set), batch):
            idx = np.arange(start, min(start + batch, len(self.val_set)))
            rgb, labels, depth = self._batch(self.val_set, idx)
            logits, _ = self.model.forward_train(normalise(rgb.to(self.device)),
                                                 None if depth is None else depth.to(self.device))
            conf += confusion(logits.argmax(1).cpu().numpy(), labels.numpy(), k, ignore=IGNORE)
            step = CALIBRATION_PIXEL_STEP
            sample_logits.append(logits[:, :, ::step, ::step].permute(0, 2, 3, 1).reshape(-1, k).cpu().numpy())
            sample_labels.append(labels[:, ::step, ::step].reshape(-1).numpy())
        sc = scores(conf, ignore=IGNORE)
        row = {"val_miou": round(sc.miou, 4), "val_mpa": round(sc.mpa, 4), "val_pixel_accuracy": round(sc.accuracy, 4)}
        return row | _calibration_row(np.concatenate(sample_logits), np.concatenate(sample_labels))

    # ------------------------------------------------------------------ the run
    def run(self, *, progress: Progress | None = None, stop_after: int | None = None) -> TrainResult:
        """Train to the last iteration (or until ``stop_after`` iterations are done, as a kill would stop it
        right after a checkpoint); Ctrl-C saves a checkpoint first."""
        s = self.s
        every_ckpt = s.checkpoint_every or s.eval_every
        losses: list[float] = []
        t0 = time.perf_counter() - self.elapsed
        try:
            while self.iteration < self.total:
                if stop_after is not None and self.iteration >= stop_after:
                    break
                losses.append(self.step())
                self.elapsed = time.perf_counter() - t0
                done = self.iteration == self.total
                if self.iteration % s.eval_every == 0 or done:
                    epoch = self.iteration * s.batch / len(self.train_set)
                    row = {"iteration": self.iteration, "epoch": round(epoch, 3),
                           "lr": round(poly_lr(s.lr, self.iteration - 1, self.total, s.poly_power), 6),
                           "train_loss": round(float(np.mean(losses)), 4), **self.evaluate(),
                           "seconds": round(self.elapsed, 1)}
                    losses = []
                    self.rows.append(row)
                    if row["val_miou"] > self.best_miou:
                        self.best_miou = row["val_miou"]
                        self._save_weights(self.best_path, row)
                    self._write_logs()
                if self.iteration % every_ckpt == 0 or done:
                    self._save_checkpoint()
                if progress is not None:
                    progress(self.iteration, self.total, self.rows[-1] if self.rows else {})
        except KeyboardInterrupt:
            self._save_checkpoint()
            raise
        if self.iteration >= self.total:
            self._save_weights(self.final_path, self.rows[-1] if self.rows else {})
        return TrainResult(s.out, self.best_path if self.best_path.exists() else None, self.final_path,
                           self.best_miou, self.iteration, list(self.rows))

    # ------------------------------------------------------------------ files
    def _save_weights(self, path: Path, row: dict) -> None:
        meta = {"network": self.spec.describe(), "iteration": self.iteration, "metrics": row,
                "settings": self.s.to_dict(), "parameters": count_parameters(self.model), "init": self.s.init}
        if "val_temperature" in row:  # the segmenter divides the logits by it (--no-calibration: not)
            meta["temperature"] = row["val_temperature"]
        save_weights(path, self.model, self.spec, self.label_set, self.s.input_size, meta)

    def _save_checkpoint(self) -> None:
        blob = {"format": CHECKPOINT_FORMAT, "config": self._config(), "iteration": self.iteration,
                "best_miou": self.best_miou, "rows": self.rows, "elapsed": self.elapsed,
                "model": {k: v.cpu() for k, v in self.model.state_dict().items()},
                "optimizer": self.optimizer.state_dict()}
        buf = io.BytesIO()
        torch.save(blob, buf)
        write_bytes_atomic(self.last_path, buf.getvalue())

    def _load_checkpoint(self) -> None:
        path = self.last_path
        if not path.is_file():
            raise ConfigError(f"{self.s.out}: nothing to resume (no last.pt)")
        blob = read_torch_file(path, "training checkpoint")
        if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
            raise FormatError(f"{path}: not a semmap training checkpoint")
        refuse_other_settings(path, blob["config"], self._config(), RESUME_KEYS)
        self.model.load_state_dict(blob["model"])
        self.model.to(self.device)
        self.optimizer.load_state_dict(blob["optimizer"])
        self.iteration, self.best_miou = int(blob["iteration"]), float(blob["best_miou"])
        self.rows, self.elapsed = list(blob["rows"]), float(blob.get("elapsed", 0.0))
        log.info("resuming %s at iteration %d of %d", self.s.out, self.iteration, self.total)

    def _write_logs(self) -> None:
        out = self.s.out
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(self.rows[0]))
        writer.writeheader()
        writer.writerows(self.rows)
        write_text_atomic(out / "log.csv", buf.getvalue())
        write_text_atomic(out / "log.json", json.dumps({"network": self.spec.describe(), "rows": self.rows,
                                                        "best_val_miou": self.best_miou}, indent=1))
        write_bytes_atomic(out / "curve.png", _curve_png(self.rows, self.spec.describe()))


def _calibration_row(logits: np.ndarray, labels: np.ndarray) -> dict:
    """The temperature fitted on validation pixels (void left out) and NLL / ECE before and after it."""
    keep = labels != IGNORE
    logits, labels = logits[keep], labels[keep]
    if len(labels) == 0:
        return {}
    t = fit_temperature(logits, labels)
    before = calibration_scores(softmax(logits), labels)
    after = calibration_scores(softmax(logits / t), labels)
    return {"val_temperature": round(t, 4), "val_nll": before["nll"], "val_nll_calibrated": after["nll"],
            "val_ece": before["ece"], "val_ece_calibrated": after["ece"]}


def _split(ds: TrainingSet, fraction: float) -> tuple[TrainingSet, TrainingSet]:
    """Hold out every round(1 / fraction)-th image for validation (frames of the same sequences: optimistic)."""
    if not 0 < fraction < 1:
        raise ConfigError(f"validation fraction must be in (0, 1), got {fraction}")
    n = len(ds)
    if n < 2:
        raise DatasetError(f"{ds.sources[0] if ds.sources else 'data'}: need at least 2 images to hold one out "
                           f"for validation (or give --val)")
    step = max(2, round(1 / fraction))
    val = np.zeros(n, bool)
    val[::step] = True
    log.warning("no --val folders: validating on %d of the %d training images (every %d-th)", val.sum(), n, step)

    def take(mask: np.ndarray) -> TrainingSet:
        return replace(ds, rgb=ds.rgb[mask], labels=ds.labels[mask],
                       depth=None if ds.depth is None else ds.depth[mask],
                       sources=[p for p, m in zip(ds.sources, mask, strict=True) if m])

    return take(~val), take(val)


def _curve_png(rows: list[dict], title: str) -> bytes:
    """Training loss and validation mIoU against iterations."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    it = [r["iteration"] for r in rows]
    fig, ax = plt.subplots(figsize=(7, 3.5), dpi=100)
    ax.plot(it, [r["train_loss"] for r in rows], color="tab:red", label="training loss")
    ax.set_xlabel("iteration")
    ax.set_ylabel("weighted cross entropy", color="tab:red")
    ax2 = ax.twinx()
    ax2.plot(it, [r["val_miou"] for r in rows], color="tab:blue", marker=".", label="validation mIoU")
    ax2.set_ylabel("validation mIoU", color="tab:blue")
    ax2.set_ylim(0, 1)
    ax.set_title(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def train(settings: TrainSettings, *, resume: bool = False, progress: Progress | None = None,
          stop_after: int | None = None) -> TrainResult:
    """Train one network as ``settings`` say (continuing ``settings.out`` with ``resume``)."""
    return Trainer(settings, resume=resume).run(progress=progress, stop_after=stop_after)
