"""``semmap adapt``: a finished run's map teaches the network that built it (Frey et al., RA-L 2022; Liu et al.,
CVPR 2023 with a NeRF), with no labels.

1. Pseudo-labels (:mod:`semmap.train.pseudo_labels`): the map's class at each pixel's 3D point of every frame the
   run mapped, seen from the pose it was mapped with, masked where the map is unsure; every ``holdout_every``-th
   frame is kept out of training (the curve, the choice of the weights and the temperature are measured there).
2. Fine-tuning from the network's own weights at its training size: SGD with the poly rate, augmentation, each
   step's batch shared between pseudo-labelled frames and replayed original training images
   (:mod:`semmap.train.replay`), every class weighed alike (median-frequency weights of so few images cost 5-7
   points of validation MIoU in 20 steps: docs/EXPERIMENTS.md), and optionally a pull towards the starting weights
   (L2-SP: ``anchor`` / 2 x squared distance; the default without replay).
3. Every ``eval_every`` steps: agreement with the held-out frames' pseudo-labels (MIoU) and MIoU on the original
   validation scenes; the weights kept (``best.pt``) are those agreeing best with the map among the evaluations
   whose validation MIoU fell by at most ``forget_tolerance`` (the starting weights when none does better).
4. Recalibration: the temperature fitted (NLL) on the held-out frames' pixels where the map has a class.

Every random choice of step ``i`` is seeded by ``(seed, i)`` and a checkpoint (``last.pt``) is written at every
evaluation, so a run killed and resumed (``resume``) continues exactly. Outputs in ``out``: ``best.pt`` (for
``--weights``), ``manifest.json`` (its entry, in the shipped manifest's form), ``report.json`` / ``report.md``
(pseudo-label coverage and accuracy, the curve's rows, CPU minutes), ``curve.png``, ``pseudo_labels.png`` and
``pseudo_labels.npz`` (the pseudo-labelled frames, read back on resume), ``log.csv``, ``last.pt``.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812  (the usual PyTorch alias)

from semmap.errors import ConfigError, DatasetError, FormatError
from semmap.eval.semantic import confusion, scores
from semmap.files.atomic import write_bytes_atomic, write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.limits import check, check_memory, check_network_input
from semmap.maps.base import SemanticMap
from semmap.perception.networks.pspnet import AUX_WEIGHT
from semmap.perception.networks.registry import read_torch_file
from semmap.train.augment import Augmentation, augment
from semmap.train.calibrate import fitted_record
from semmap.train.class_weights import IGNORE, median_frequency_weights
from semmap.train.data import DEPTH_MM, TrainingSet
from semmap.train.pseudo_labels import (
    MaskSettings,
    PseudoLabelStats,
    ViewCounter,
    confident_network,
    pseudo_labels,
)
from semmap.train.replay import REPLAY_FRAMES, REPLAY_SCENES, find_replay
from semmap.train.trainable import Trainable, load_trainable
from semmap.train.trainer import (
    batch_indices,
    batch_tensors,
    normalise,
    poly_lr,
    refuse_other_settings,
    seed_of,
    seeded,
)
from semmap.types import Frame, Trajectory

log = logging.getLogger("semmap")

CHECKPOINT_FORMAT = "semmap-adapt-checkpoint"
#: The pseudo-labelled frames of a run (written once, read back on ``resume``).
DATA_FILE = "pseudo_labels.npz"
#: The weights chosen so far (the best evaluation's), recalibrated into ``best.pt`` at the end.
CANDIDATE_FILE = "candidate.state"
#: A frame's pose in ``trajectory.txt`` lies within this of its timestamp (TUM files keep 6 decimals).
POSE_TIME_TOLERANCE = 1e-3
#: Held-out pixels the temperature is fitted on: every n-th row and column.
CALIBRATION_PIXEL_STEP = 4
#: Pull towards the starting weights when there is nothing to replay (``anchor`` left at None).
ANCHOR_WITHOUT_REPLAY = 1.0
#: The network's confident labels veto the map's only where it agrees with the map on at least this share of the
#: pixels: a network far from the frames' domain (a simulator network on real frames) is sure and wrong alike.
VETO_MIN_AGREEMENT = 0.5
#: Every n-th mapped frame measures that agreement.
AGREEMENT_EVERY = 10
#: Frames shown in ``pseudo_labels.png``.
PREVIEW_FRAMES = 4
#: Settings that must match to resume.
RESUME_KEYS = ("steps", "batch", "replay_share", "lr", "momentum", "weight_decay", "poly_power", "anchor", "every",
               "holdout_every", "eval_every", "seed", "augment", "masks", "replay_scenes", "replay_frames",
               "forget_tolerance", "freeze_norm", "class_weighting")

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class AdaptSettings:
    """One adaptation: ``steps`` SGD steps of ``batch`` images, ``replay_share`` of them replayed."""

    out: Path
    steps: int = 300
    batch: int = 8
    replay_share: float = 0.5
    lr: float = 0.01
    momentum: float = 0.9
    weight_decay: float = 1e-4
    poly_power: float = 0.9
    anchor: float | None = None  #: L2-SP weight (None: 0 with replay, ANCHOR_WITHOUT_REPLAY without)
    every: int = 1  #: pseudo-label every n-th mapped frame
    holdout_every: int = 8  #: every n-th of those is kept out of training
    eval_every: int = 50
    seed: int = 0
    threads: int | None = None
    augment: bool = True
    masks: MaskSettings = field(default_factory=MaskSettings)
    replay_folders: tuple[Path, ...] = ()
    replay_scenes: int = REPLAY_SCENES
    replay_frames: int = REPLAY_FRAMES
    forget_tolerance: float = 0.01  #: validation MIoU the kept weights may lose (0.01 = 1 point)
    freeze_norm: bool = False  #: BatchNorm keeps its statistics (eval mode) while the weights move
    class_weighting: bool = False  #: median-frequency class weights of the pseudo-labels and replay (else alike)

    def __post_init__(self) -> None:
        check("iterations", self.steps, "--steps")
        check("batch", self.batch, "--batch")
        check("learning_rate", self.lr, "--lr")
        check("probability", self.replay_share, "--replay-share")
        check("every_positive", self.every, "--every")
        check("every_positive", self.eval_every, "--eval-every")
        check("seed", self.seed, "--seed")
        check("threads", self.threads, "--threads")
        check("probability", self.masks.min_confidence, "--min-confidence")
        check("every", self.masks.min_views, "--min-views")
        if self.holdout_every < 2:
            raise ConfigError(f"holdout_every must be at least 2 (one frame in n kept out), got {self.holdout_every}")
        if self.anchor is not None and not (np.isfinite(self.anchor) and self.anchor >= 0):
            raise ConfigError(f"--anchor must be a number >= 0, got {self.anchor}")
        if self.batch < 2 and self.replay_share > 0:
            raise ConfigError("--batch must be at least 2 to share it between pseudo-labelled and replayed images "
                              "(or --replay-share 0)")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["out"] = str(self.out)
        d["replay_folders"] = [str(p) for p in self.replay_folders]
        d["masks"] = self.masks.to_dict()
        return d


@dataclass
class AdaptSource:
    """What adaptation reads of a finished run: its frames (read twice, in order), the poses they were mapped
    with, its final map and the weight file of its segmenter."""

    run_dir: Path
    frames: Callable[[], Iterable[Frame]]
    length: int  #: frames the dataset holds (for progress)
    trajectory: Trajectory
    map: SemanticMap
    weights: Path
    segmenter: str
    min_depth: float
    max_depth: float
    command: str = ""


@dataclass
class AdaptResult:
    """What an adaptation produced: the weight file for ``--weights``, its report, and the output folder."""

    out: Path
    weights: Path
    report: dict = field(default_factory=dict)


@dataclass
class PseudoData:
    """The pseudo-labelled frames at the network's input size: training images (``train``), held-out images
    (``holdout``), each held-out frame's unmasked map labels (for the temperature), and the statistics."""

    train: TrainingSet
    holdout: TrainingSet
    holdout_map: np.ndarray  # (M, H, W) uint16, 0 where the map has no class
    truth_train: np.ndarray | None  # (N, H, W) uint16 true labels where the frames carry them
    truth_holdout: np.ndarray | None
    names: list[str]  # frame names, training then held-out
    stats: dict


def _hash_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _posed_frames(source: AdaptSource) -> Iterable[tuple[int, Frame, np.ndarray]]:
    """(index among the mapped frames, frame, the pose it was mapped with) of the frames in ``trajectory.txt``."""
    stamps = source.trajectory.timestamps
    if not len(stamps):
        return
    used = 0
    for frame in source.frames():
        j = int(np.searchsorted(stamps, frame.timestamp))
        j = min((c for c in (j - 1, j) if 0 <= c < len(stamps)), key=lambda c: abs(stamps[c] - frame.timestamp))
        if abs(stamps[j] - frame.timestamp) > POSE_TIME_TOLERANCE:
            continue
        yield used, frame, source.trajectory.poses[j]
        used += 1


class Adapter:
    """Holds the pseudo-labelled frames, the replay, the network and its optimiser; :meth:`run` adapts to the
    end (or ``stop_after`` steps, as a kill would stop it after a checkpoint)."""

    def __init__(self, source: AdaptSource, settings: AdaptSettings, *, resume: bool = False,
                 progress: Progress | None = None) -> None:
        self.source, self.s = source, settings
        self.progress = progress or (lambda stage, i, n: None)
        out = settings.out
        check_outputs([("--out", out, OutputKind.FOLDER)],
                      [("RUN_DIR", source.run_dir), ("--weights", source.weights),
                       *(("--replay", p) for p in settings.replay_folders)])
        self.last_path, self.candidate_path = out / "last.pt", out / CANDIDATE_FILE
        if not resume and self.last_path.exists():
            raise ConfigError(f"{out}: holds an adaptation already (last.pt); continue it with --resume or choose "
                              f"another --out")
        if resume and not self.last_path.is_file():
            raise ConfigError(f"{out}: nothing to resume (no last.pt)")
        if settings.threads is not None:
            torch.set_num_threads(int(settings.threads))
        self.cpu_s = 0.0
        self._cpu0 = time.process_time()
        self.net: Trainable = load_trainable(source.segmenter, source.weights)
        self.model = self.net.model
        self.weights_sha256 = _hash_file(source.weights)
        if source.map.label_set is None:
            raise ConfigError(f"{source.run_dir}: the run's map holds no classes; a map built with its segmenter is "
                              "needed")
        self.lut = self.net.lut(source.map.label_set)
        out.mkdir(parents=True, exist_ok=True)
        self.data = self._load_data() if resume and (out / DATA_FILE).is_file() else self._make_data()
        self.input_size = (self.data.train.rgb.shape[2], self.data.train.rgb.shape[1])
        self.replay = find_replay(self.net.meta, source.weights, self.input_size, self.net.label_set,
                                  need_depth=self.uses_depth, folders=settings.replay_folders,
                                  shipped_manifest=_shipped_manifest(), scenes=settings.replay_scenes,
                                  frames=settings.replay_frames, cache=_replay_cache())
        if self.replay.train is None and settings.replay_share > 0:
            log.warning("no original training data to replay for %s (give --replay DATA_FOLDER); adapting with a "
                        "pull towards the starting weights instead", source.weights)
        self.anchor = (settings.anchor if settings.anchor is not None
                       else (0.0 if self.replay.train is not None else ANCHOR_WITHOUT_REPLAY))
        k = len(self.net.label_set)
        parts = [self.data.train.labels] + ([] if self.replay.train is None else [self.replay.train.labels])
        self.class_weights = (median_frequency_weights(np.concatenate(parts), k) if settings.class_weighting
                              else (np.arange(k) != IGNORE).astype(np.float32))
        self.start = {name: p.detach().clone() for name, p in self.model.named_parameters()}
        self.optimizer = torch.optim.SGD(self.model.parameters(), lr=settings.lr, momentum=settings.momentum,
                                         weight_decay=settings.weight_decay)
        self.iteration = 0
        self.rows: list[dict] = []
        self.best: dict = {}
        self.start_val: float | None = None
        if resume:
            self._load_checkpoint()

    @property
    def uses_depth(self) -> bool:
        return self.net.uses_depth

    # ------------------------------------------------------------------ pseudo-labelled frames
    def _make_data(self) -> PseudoData:
        """Both passes over the run's frames: views per voxel, then pseudo-labels at the network's input size."""
        src, s = self.source, self.s
        views, stride, (w, h), mapped, agreement = self._first_pass()
        veto = s.masks.network_confidence if agreement >= VETO_MIN_AGREEMENT else None
        used = (mapped + s.every - 1) // s.every
        check_network_input(w, h, s.batch, training=True)
        check_memory(f"{used} pseudo-labelled frames at {w}x{h}", used * w * h * (3 + 2 * 4))
        k = len(self.net.label_set)
        rgb, labels, depth, truth, maps, names, hold = [], [], [], [], [], [], []
        stats = PseudoLabelStats(k)
        for i, frame, T in _posed_frames(src):
            if i % s.every:
                continue
            p = pseudo_labels(src.map, frame, T, views, s.masks, stride=stride, class_lut=self.lut,
                              min_depth=src.min_depth, max_depth=src.max_depth)
            rgb_in = _resized(frame.rgb, (w, h), self.net.interpolation)
            depth_in = _depth_mm(frame, (w, h)) if self.uses_depth else None
            if depth_in is not None:
                depth.append(depth_in)
            grid = p.labels.shape
            pred, conf = (_resized(a, (grid[1], grid[0]), cv2.INTER_NEAREST) for a in self._top(rgb_in, depth_in))
            confident_network(p, pred, conf, veto)
            truth_grid = None
            if frame.labels is not None:
                truth_grid = frame.labels[::stride, ::stride].astype(np.uint16)
                truth.append(_resized(truth_grid, (w, h), cv2.INTER_NEAREST))
            stats.add(p, truth_grid, pred)
            rgb.append(rgb_in)
            labels.append(_resized(p.labels, (w, h), cv2.INTER_NEAREST))
            maps.append(_resized(p.map_labels, (w, h), cv2.INTER_NEAREST))
            names.append(frame.name or str(frame.index))
            hold.append((i // s.every) % s.holdout_every == s.holdout_every - 1)
            self.progress("pseudo-labels", i + 1, mapped)
        hold_mask = np.asarray(hold, bool)
        if hold_mask.all() or not hold_mask.any():  # too few frames to keep one out: the last one is
            hold_mask[:] = False
            hold_mask[-1] = True
        if hold_mask.all():
            raise DatasetError(f"{src.run_dir}: only one mapped frame; adaptation needs at least two")
        has_truth = len(truth) == len(rgb)
        rgb_a, lab_a, map_a = np.stack(rgb), np.stack(labels), np.stack(maps)
        depth_a = np.stack(depth) if self.uses_depth else None
        truth_a = np.stack(truth) if has_truth else None
        summary = stats.summary() | {"network_agreement": round(agreement, 4), "network_veto": veto is not None}
        data = self._split(rgb_a, lab_a, depth_a, map_a, truth_a, hold_mask, names, summary)
        if not data.train.labels.any():
            raise DatasetError(f"{src.run_dir}: the map is unsure of every pixel (no pseudo-label survived the "
                               f"masks: {json.dumps(data.stats['removed'])}); lower --min-confidence / --min-views")
        self._save_data(rgb_a, lab_a, depth_a, map_a, truth_a, hold_mask, names, data.stats)
        return data

    def _first_pass(self) -> tuple[ViewCounter, int, tuple[int, int], int, float]:
        """Frames per voxel over every mapped frame, the rendering stride, the network's input size, the frames
        mapped, and how often the network agrees with the map (every ``AGREEMENT_EVERY``-th frame's pixels where
        the map has a class)."""
        src = self.source
        views = ViewCounter(src.map.resolution)
        stride, size, mapped, agree, total = 1, (0, 0), 0, 0, 0
        for i, frame, T in _posed_frames(src):
            size = self.net.input_for(frame.intrinsics.width, frame.intrinsics.height)
            stride = max(1, round(frame.intrinsics.width / size[0]))
            views.add(frame, T, stride=stride, min_depth=src.min_depth, max_depth=src.max_depth)
            if i % AGREEMENT_EVERY == 0:
                p = pseudo_labels(src.map, frame, T, None, self.s.masks, stride=stride, class_lut=self.lut,
                                  min_depth=src.min_depth, max_depth=src.max_depth)
                depth_in = _depth_mm(frame, size) if self.uses_depth else None
                pred = self._top(_resized(frame.rgb, size, self.net.interpolation), depth_in)[0]
                pred = _resized(pred, (p.map_labels.shape[1], p.map_labels.shape[0]), cv2.INTER_NEAREST)
                has = p.map_labels != IGNORE
                agree, total = agree + int((pred[has] == p.map_labels[has]).sum()), total + int(has.sum())
            mapped = i + 1
            self.progress("counting views", i + 1, src.length)
        if mapped == 0:
            raise DatasetError(f"{src.run_dir}: none of the sequence's frames has a pose in trajectory.txt (is it "
                               "the sequence this run mapped?)")
        return views, stride, size, mapped, agree / max(total, 1)

    @torch.no_grad()
    def _top(self, rgb: np.ndarray, depth: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The starting network's class (uint16) and its probability (float32) at each pixel of one image at the
        input size (``depth`` in millimetres, for a network that uses it)."""
        self.model.eval()
        x = torch.from_numpy(rgb[None]).permute(0, 3, 1, 2).float().div_(255.0)
        d = None if depth is None else torch.from_numpy(depth[None, None].astype(np.float32) / DEPTH_MM)
        logits, _ = self._forward(x, d)
        conf, top = torch.softmax(logits[0], 0).max(0)
        return top.numpy().astype(np.uint16), conf.numpy().astype(np.float32)

    def _split(self, rgb, labels, depth, maps, truth, hold, names, stats) -> PseudoData:
        ls = self.net.label_set

        def part(mask):
            return TrainingSet(rgb[mask], labels[mask], None if depth is None else depth[mask], ls,
                               [n for n, m in zip(names, mask, strict=True) if m])

        train, holdout = part(~hold), part(hold)
        return PseudoData(train, holdout, maps[hold], None if truth is None else truth[~hold],
                          None if truth is None else truth[hold], train.sources + holdout.sources, stats)

    def _save_data(self, rgb, labels, depth, maps, truth, hold, names, stats) -> None:
        arrays = {"rgb": rgb, "labels": labels, "map_labels": maps, "holdout": hold,
                  "names": np.asarray(names, dtype=str), "stats": np.asarray(json.dumps(stats))}
        if depth is not None:
            arrays["depth"] = depth
        if truth is not None:
            arrays["truth"] = truth
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        write_bytes_atomic(self.s.out / DATA_FILE, buf.getvalue())

    def _load_data(self) -> PseudoData:
        path = self.s.out / DATA_FILE
        try:
            with np.load(path) as z:
                a = {name: z[name] for name in z.files}
            stats = json.loads(str(a["stats"]))
            return self._split(a["rgb"], a["labels"], a.get("depth"), a["map_labels"], a.get("truth"),
                               a["holdout"].astype(bool), [str(n) for n in a["names"]], stats)
        except (OSError, ValueError, KeyError) as exc:
            raise FormatError(f"{path}: unreadable pseudo-labelled frames ({type(exc).__name__}); delete the "
                              f"folder and adapt again") from None

    # ------------------------------------------------------------------ one step
    def _forward(self, rgb: torch.Tensor, depth: torch.Tensor | None):
        return self.model.forward_train(normalise(rgb), depth)

    def _loss(self, logits: torch.Tensor, labels: torch.Tensor) -> torch.Tensor | None:
        """Weighted cross entropy over the labelled pixels (None when every pixel is ignored)."""
        if not bool((labels != IGNORE).any()):
            return None
        w = torch.from_numpy(self.class_weights)
        return F.cross_entropy(logits, labels, weight=w, ignore_index=IGNORE)

    def step(self) -> dict:
        """One SGD step; its losses (pseudo-labels, replay, pull towards the start)."""
        s, it = self.s, self.iteration
        n_r = round(s.batch * s.replay_share) if self.replay.train is not None else 0
        n_r = min(n_r, s.batch - 1)
        n_p = s.batch - n_r
        parts = [batch_tensors(self.data.train, batch_indices(s.seed, it, n_p, len(self.data.train)),
                               self.uses_depth)]
        if n_r:
            parts.append(batch_tensors(self.replay.train, batch_indices(s.seed + 1, it, n_r, len(self.replay.train)),
                                       self.uses_depth))
        rgb = torch.cat([p[0] for p in parts])
        labels = torch.cat([p[1] for p in parts])
        depth = None if not self.uses_depth else torch.cat([p[2] for p in parts])
        rgb, labels, depth = augment(rgb, labels, depth, Augmentation(enabled=s.augment), seeded(s.seed, it, 2))
        torch.manual_seed(seed_of(s.seed, it, 3))  # dropout
        for group in self.optimizer.param_groups:
            group["lr"] = poly_lr(s.lr, it, s.steps, s.poly_power)
        self.model.train()
        if s.freeze_norm:
            for module in self.model.modules():
                if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                    module.eval()
        logits, aux = self._forward(rgb, depth)
        row: dict = {}
        total = torch.zeros(())
        for name, sl, share in (("pseudo_loss", slice(0, n_p), n_p / s.batch),
                                ("replay_loss", slice(n_p, s.batch), n_r / s.batch)):
            if share == 0:
                continue
            loss = self._loss(logits[sl], labels[sl])
            if loss is None:
                continue
            if aux is not None:
                loss = loss + AUX_WEIGHT * self._loss(aux[sl], labels[sl])
            row[name] = float(loss.detach())
            total = total + share * loss
        if self.anchor > 0:
            pull = sum(((p - self.start[n]) ** 2).sum() for n, p in self.model.named_parameters())
            total = total + 0.5 * self.anchor * pull
            row["anchor_loss"] = float(0.5 * self.anchor * pull.detach())
        if not torch.isfinite(total):
            raise ConfigError(f"adaptation diverged at step {it} (loss {float(total)}); lower --lr")
        self.optimizer.zero_grad(set_to_none=True)
        if total.requires_grad:
            total.backward()
            self.optimizer.step()
        self.iteration += 1
        row["loss"] = float(total.detach())
        return row

    # ------------------------------------------------------------------ evaluation
    @torch.no_grad()
    def _logits(self, ds: TrainingSet, batch: int = 8):
        """(index, logits (K, H, W)) of every image of ``ds`` at the training size, in eval mode."""
        self.model.eval()
        for start in range(0, len(ds), batch):
            idx = np.arange(start, min(start + batch, len(ds)))
            rgb, _, depth = batch_tensors(ds, idx, self.uses_depth)
            logits, _ = self._forward(rgb, depth)
            for j, i in enumerate(idx):
                yield int(i), logits[j]

    def _predictions(self, ds: TrainingSet):
        for i, lg in self._logits(ds):
            yield i, lg.argmax(0).numpy().astype(np.uint16)

    def evaluate(self) -> dict:
        """Agreement with the held-out pseudo-labels (MIoU, loss), MIoU against the held-out frames' true labels
        (where they exist: reported, never used to choose) and on the original validation images."""
        k = len(self.net.label_set)
        hold = self.data.holdout
        conf_p = np.zeros((k, k), np.int64)
        conf_t = np.zeros((k, k), np.int64)
        losses = []
        w = torch.from_numpy(self.class_weights)
        for i, lg in self._logits(hold):
            y = torch.from_numpy(hold.labels[i].astype(np.int64))
            pred = lg.argmax(0).numpy()
            conf_p += confusion(pred, hold.labels[i], k, ignore=IGNORE)
            if bool((y != IGNORE).any()):
                losses.append(float(F.cross_entropy(lg[None], y[None], weight=w, ignore_index=IGNORE)))
            if self.data.truth_holdout is not None:
                conf_t += confusion(pred, self.data.truth_holdout[i], k, ignore=IGNORE)
        row = {"holdout_pseudo_miou": round(scores(conf_p, ignore=IGNORE).miou, 4),
               "holdout_pseudo_loss": round(float(np.mean(losses)), 4) if losses else None}
        if self.data.truth_holdout is not None:
            row["holdout_truth_miou"] = round(scores(conf_t, ignore=IGNORE).miou, 4)
        if self.replay.val is not None:
            conf_v = np.zeros((k, k), np.int64)
            for i, pred in self._predictions(self.replay.val):
                conf_v += confusion(pred, self.replay.val.labels[i], k, ignore=IGNORE)
            row["val_miou"] = round(scores(conf_v, ignore=IGNORE).miou, 4)
        return row

    def _eligible(self, row: dict) -> bool:
        """Whether an evaluation's weights forgot no more than the tolerance on the validation images."""
        if self.start_val is None or "val_miou" not in row:
            return True
        return row["val_miou"] >= self.start_val - self.s.forget_tolerance - 1e-9

    def _record(self, row: dict) -> None:
        """Log an evaluation and keep its weights when they agree best with the map so far."""
        self.rows.append(row)
        if row["step"] == 0:
            self.start_val = row.get("val_miou")
        score = row["holdout_pseudo_miou"]
        if self._eligible(row) and (not self.best or score > self.best["holdout_pseudo_miou"]):
            self.best = {"step": row["step"], "holdout_pseudo_miou": score, "val_miou": row.get("val_miou")}
            buf = io.BytesIO()
            torch.save({k: v.detach().cpu() for k, v in self.model.state_dict().items()}, buf)
            write_bytes_atomic(self.candidate_path, buf.getvalue())
        self._write_logs()

    # ------------------------------------------------------------------ the run
    def _tick(self) -> None:
        now = time.process_time()
        self.cpu_s += now - self._cpu0
        self._cpu0 = now

    def run(self, *, stop_after: int | None = None) -> AdaptResult | None:
        """Adapt to the last step and write the outputs (None when stopped by ``stop_after`` first)."""
        s = self.s
        if not self.rows:
            self._record({"step": 0, "lr": s.lr, **self.evaluate()})
            self._tick()
            self._save_checkpoint()
        losses: list[dict] = []
        try:
            while self.iteration < s.steps:
                if stop_after is not None and self.iteration >= stop_after:
                    return None
                losses.append(self.step())
                done = self.iteration == s.steps
                if self.iteration % s.eval_every == 0 or done:
                    mean = {key: round(float(np.mean([r[key] for r in losses if key in r])), 4)
                            for key in ("loss", "pseudo_loss", "replay_loss", "anchor_loss")
                            if any(key in r for r in losses)}
                    losses = []
                    lr = poly_lr(s.lr, self.iteration - 1, s.steps, s.poly_power)
                    self._tick()
                    self._record({"step": self.iteration, "lr": round(lr, 6), **mean, **self.evaluate(),
                                  "cpu_s": round(self.cpu_s, 1)})
                    self._tick()
                    self._save_checkpoint()
                self.progress("adapting", self.iteration, s.steps)
        except KeyboardInterrupt:
            self._tick()
            self._save_checkpoint()
            raise
        return self._finish()

    def _finish(self) -> AdaptResult:
        """The chosen weights recalibrated into ``best.pt``, with the manifest entry and the report."""
        s = self.s
        self.model.load_state_dict(read_torch_file(self.candidate_path, "adaptation candidate"))
        record = self._calibrate()
        meta = self._meta(record)
        best = self.net.save(s.out / f"best{self.net.suffix}", meta)
        preview = self._preview()
        self._tick()
        report = self._report(best, record, preview)
        self._write_manifest(best, meta, report)
        write_text_atomic(s.out / "report.json", json.dumps(report, indent=2))
        write_text_atomic(s.out / "report.md", report_markdown(report))
        self.candidate_path.unlink(missing_ok=True)
        return AdaptResult(s.out, best, report)

    def _calibrate(self) -> dict:
        """The temperature fitted on the held-out frames' pixels where the map has a class (every 4th row and
        column), with NLL / ECE before and after; the starting network's when there is no such pixel."""
        k = len(self.net.label_set)
        step = CALIBRATION_PIXEL_STEP
        z, y = [], []
        for i, lg in self._logits(self.data.holdout):
            target = self.data.holdout_map[i, ::step, ::step].reshape(-1).astype(np.int64)
            keep = target != IGNORE
            z.append(lg[:, ::step, ::step].permute(1, 2, 0).reshape(-1, k).numpy()[keep])
            y.append(target[keep])
        if not y or not sum(len(v) for v in y):
            t = float(self.net.meta.get("temperature", 1.0))
            return {"temperature": t, "fitted_on": "none (no held-out pixel with a map class): the starting "
                                                   "network's temperature"}
        record = fitted_record(np.concatenate(z), np.concatenate(y))
        record["images"] = len(self.data.holdout)
        record["fitted_on"] = ("held-out frames of the adapted run, every 4th pixel row and column where the map "
                               "has a class, the map's class as the target")
        return record

    def _meta(self, calibration: dict) -> dict:
        src = self.source
        meta = {k: v for k, v in self.net.meta.items() if k not in ("temperature", "calibration", "replay",
                                                                      "adapted_from", "adapt")}
        origin = self.net.meta.get("adapted_from") or {"file": str(src.weights), "sha256": self.weights_sha256,
                                                       "network": self.net.network}
        meta.update({"temperature": calibration["temperature"], "calibration": calibration,
                     "adapted_from": origin,
                     "adapt": {"run": str(src.run_dir), "weights": str(src.weights),
                               "weights_sha256": self.weights_sha256, "best_step": self.best.get("step"),
                               "steps": self.s.steps, "settings": self.s.to_dict(),
                               "pseudo_labels": self.data.stats}})
        if self.replay.plan is not None:
            meta["replay"] = self.replay.plan.to_dict()
        return meta

    def _report(self, best: Path, calibration: dict, preview: Path | None) -> dict:
        src = self.source
        return {"run": str(src.run_dir), "segmenter": src.segmenter, "weights": str(src.weights),
                "network": self.net.network, "out": str(best),
                "frames": {"train": len(self.data.train), "holdout": len(self.data.holdout)},
                "pseudo_labels": self.data.stats, "masks": self.s.masks.to_dict(),
                "replay": self.replay.describe(), "anchor": self.anchor,
                "class_weights": {n: round(float(w), 4) for n, w in zip(self.net.label_set.names,
                                                                        self.class_weights, strict=True)},
                "steps": self.s.steps, "best": self.best, "start": self.rows[0] if self.rows else {},
                "chosen": next((r for r in self.rows if r["step"] == self.best.get("step")), {}),
                "calibration": calibration, "rows": self.rows, "cpu_minutes": round(self.cpu_s / 60.0, 2),
                "settings": self.s.to_dict(),
                "files": {"weights": str(best), "curve": str(self.s.out / "curve.png"),
                          **({"preview": str(preview)} if preview is not None else {})}}

    def _write_manifest(self, best: Path, meta: dict, report: dict) -> None:
        """``manifest.json`` beside ``best.pt``: its entry in the form of ``weights/manifest.json``."""
        data = best.read_bytes()
        entry = {"file": best.name, "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data),
                 "network": self.net.network, "spec": self.net.spec,
                 "parameters": sum(p.numel() for p in self.model.parameters()),
                 "input_size": list(self.input_size), "command": self.source.command,
                 "adapted_from": meta["adapted_from"], "run": str(self.source.run_dir),
                 "best_step": self.best.get("step"), "steps": self.s.steps,
                 "pseudo_labels": self.data.stats, "replay": self.replay.describe(),
                 "temperature": meta["temperature"], "calibration": meta["calibration"],
                 "chosen": report["chosen"], "start": report["start"], "cpu_minutes": report["cpu_minutes"]}
        manifest = {"about": "A network semmap adapted to one mapped scene (semmap adapt); see report.md",
                    "networks": {self.net.name: entry}}
        write_text_atomic(self.s.out / "manifest.json", json.dumps(manifest, indent=1))

    # ------------------------------------------------------------------ files
    def _save_checkpoint(self) -> None:
        blob = {"format": CHECKPOINT_FORMAT, "settings": self._resume_settings(), "weights": self.weights_sha256,
                "iteration": self.iteration, "rows": self.rows, "best": self.best, "start_val": self.start_val,
                "cpu_s": self.cpu_s, "model": {k: v.cpu() for k, v in self.model.state_dict().items()},
                "optimizer": self.optimizer.state_dict()}
        buf = io.BytesIO()
        torch.save(blob, buf)
        write_bytes_atomic(self.last_path, buf.getvalue())

    def _resume_settings(self) -> dict:
        d = self.s.to_dict()
        return {k: d[k] for k in RESUME_KEYS}

    def _load_checkpoint(self) -> None:
        blob = read_torch_file(self.last_path, "adaptation checkpoint")
        if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
            raise FormatError(f"{self.last_path}: not a semmap adaptation checkpoint")
        refuse_other_settings(self.last_path, blob["settings"], self._resume_settings(), RESUME_KEYS)
        if blob.get("weights") != self.weights_sha256:
            raise ConfigError(f"{self.last_path}: this adaptation started from other weights than "
                              f"{self.source.weights}")
        self.model.load_state_dict(blob["model"])
        self.optimizer.load_state_dict(blob["optimizer"])
        self.iteration, self.rows, self.best = int(blob["iteration"]), list(blob["rows"]), dict(blob["best"])
        self.start_val, self.cpu_s = blob["start_val"], float(blob["cpu_s"])
        log.info("resuming %s at step %d of %d", self.s.out, self.iteration, self.s.steps)

    def _write_logs(self) -> None:
        keys = list(dict.fromkeys(k for r in self.rows for k in r))
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=keys)
        writer.writeheader()
        writer.writerows(self.rows)
        write_text_atomic(self.s.out / "log.csv", buf.getvalue())
        write_bytes_atomic(self.s.out / "curve.png", _curve_png(self.rows, f"{self.net.network} adapted"))

    def _preview(self) -> Path | None:
        """``pseudo_labels.png``: a few held-out frames as colour | network before | map (pseudo-labels, black
        where masked) | network after | true labels (when there are any)."""
        from semmap.viz.preview import side_by_side, write_png

        hold = self.data.holdout
        if not len(hold):
            return None
        picks = np.unique(np.linspace(0, len(hold) - 1, min(PREVIEW_FRAMES, len(hold))).round().astype(int))
        sub = TrainingSet(hold.rgb[picks], hold.labels[picks], None if hold.depth is None else hold.depth[picks],
                          hold.label_set)
        after = dict(self._predictions(sub))
        current = {k: v.detach().clone() for k, v in self.model.state_dict().items()}
        self.model.load_state_dict(self._start_state())
        before = dict(self._predictions(sub))
        self.model.load_state_dict(current)
        colors = np.asarray(self.net.label_set.colors, np.uint8).copy()
        colors[IGNORE] = 0
        rows = []
        titles = ["colour", "network before", "map (pseudo-labels)", "network after"]
        if self.data.truth_holdout is not None:
            titles.append("true labels")
        for j, i in enumerate(picks):
            panels = [sub.rgb[j], colors[before[j]], colors[sub.labels[j]], colors[after[j]]]
            if self.data.truth_holdout is not None:
                panels.append(colors[self.data.truth_holdout[i]])
            rows.append(side_by_side(panels, titles if j == 0 else [""] * len(panels)))
        width = max(r.shape[1] for r in rows)
        image = np.concatenate([np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0)), constant_values=255)
                                for r in rows])
        path = self.s.out / "pseudo_labels.png"
        write_png(path, image)
        return path

    def _start_state(self) -> dict:
        """The starting network's state dict (its file, read again: BatchNorm statistics included)."""
        return load_trainable(self.source.segmenter, self.source.weights).model.state_dict()


def _resized(image: np.ndarray, size: tuple[int, int], interpolation: int) -> np.ndarray:
    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    if interpolation == cv2.INTER_AREA and (image.shape[1] < size[0] or image.shape[0] < size[1]):
        interpolation = cv2.INTER_LINEAR
    return cv2.resize(image, size, interpolation=interpolation)


def _depth_mm(frame: Frame, size: tuple[int, int]) -> np.ndarray:
    """The frame's depth at ``size`` (nearest neighbour) as uint16 millimetres, 0 where invalid."""
    dm = np.nan_to_num(_resized(frame.depth, size, cv2.INTER_NEAREST))
    return np.clip(np.rint(dm * DEPTH_MM), 0, 65535).astype(np.uint16)


def _shipped_manifest() -> Path:
    from semmap.perception.registry import MANIFEST, shipped_weights_dir

    return shipped_weights_dir() / MANIFEST


def _replay_cache() -> Path:
    from semmap.train.replay import cache_dir

    return cache_dir()


def _curve_png(rows: list[dict], title: str) -> bytes:
    """Losses (training, held-out pseudo-labels) and MIoU (held-out pseudo-labels, validation) against steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5), dpi=100)
    for key, color, label in (("pseudo_loss", "tab:red", "training loss, pseudo-labels"),
                              ("replay_loss", "tab:orange", "training loss, replay"),
                              ("holdout_pseudo_loss", "tab:purple", "held-out loss, pseudo-labels")):
        pts = [(r["step"], r[key]) for r in rows if r.get(key) is not None]
        if pts:
            ax.plot(*zip(*pts, strict=True), color=color, marker=".", label=label)
    ax.set_xlabel("step")
    ax.set_ylabel("weighted cross entropy")
    ax2 = ax.twinx()
    for key, color, label in (("holdout_pseudo_miou", "tab:blue", "held-out MIoU vs map"),
                              ("val_miou", "tab:green", "validation MIoU (forgetting)"),
                              ("holdout_truth_miou", "tab:gray", "held-out MIoU vs truth")):
        pts = [(r["step"], r[key]) for r in rows if r.get(key) is not None]
        if pts:
            ax2.plot(*zip(*pts, strict=True), color=color, marker="x", linestyle="--", label=label)
    ax2.set_ylabel("MIoU")
    ax2.set_ylim(0, 1)
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], fontsize=7, loc="lower left")
    ax.set_title(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def report_markdown(report: dict) -> str:
    """``report.md``: what was adapted, the pseudo-labels and the curve, to read."""
    p = report["pseudo_labels"]
    lines = [f"# semmap adapt: {report['network']}", "",
             f"Run `{report['run']}`, segmenter `{report['segmenter']}`, weights `{report['weights']}` -> "
             f"`{report['out']}`.", "",
             "## Pseudo-labels", "",
             f"{p['frames']} frames ({report['frames']['train']} trained on, {report['frames']['holdout']} held out); "
             f"{p['coverage']:.1%} of the pixels with a depth kept a label.", "",
             "| removed because | share of the pixels with a depth |", "|---|---|"]
    lines += [f"| {reason.replace('_', ' ')} | {share:.1%} |" for reason, share in p["removed"].items()]
    if "accuracy" in p:
        lines += ["", "Against the frames' true labels, on the kept pixels:", "",
                  "| labels | pixel accuracy | MIoU |", "|---|---|---|",
                  f"| pseudo-labels (the map) | {p['accuracy']:.3f} | {p['miou']:.3f} |"]
        if "network_accuracy" in p:
            lines.append(f"| the network before adapting | {p['network_accuracy']:.3f} | {p['network_miou']:.3f} |")
        lines.append(f"| the map before masking (all its pixels) | {p['map_accuracy']:.3f} | {p['map_miou']:.3f} |")
    lines += ["", "## Adaptation", "",
              f"{report['steps']} steps; replay: {report['replay']['source']} ({report['replay']['images']} images, "
              f"{report['replay']['val_images']} validation images); pull towards the start {report['anchor']:g}. "
              f"Kept: step {report['best'].get('step')}. CPU time {report['cpu_minutes']:.1f} min.", "",
              "| step | loss | held-out MIoU vs map | validation MIoU | held-out MIoU vs truth |",
              "|---|---|---|---|---|"]
    for r in report["rows"]:
        lines.append(f"| {r['step']} | {_fmt(r.get('loss'))} | {_fmt(r.get('holdout_pseudo_miou'))} | "
                     f"{_fmt(r.get('val_miou'))} | {_fmt(r.get('holdout_truth_miou'))} |")
    c = report["calibration"]
    lines += ["", f"Temperature {c['temperature']:.3f} ({c.get('fitted_on', '')}).", "", "![curve](curve.png)", ""]
    if "preview" in report["files"]:
        lines += ["![pseudo-labels](pseudo_labels.png)", ""]
    return "\n".join(lines)


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def adapt(source: AdaptSource, settings: AdaptSettings, *, resume: bool = False, progress: Progress | None = None,
          stop_after: int | None = None) -> AdaptResult | None:
    """Adapt ``source``'s network to its map as ``settings`` say (continuing ``settings.out`` with ``resume``)."""
    return Adapter(source, settings, resume=resume, progress=progress).run(stop_after=stop_after)
