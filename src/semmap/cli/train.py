"""``semmap train``: a segmentation network trained on simulated or labelled images."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from semmap.cli.options import MemoryBudget, budget, parse_size
from semmap.cli.terminal import setup_logging, stderr_console
from semmap.errors import SemmapError
from semmap.perception.networks.registry import MODELS


def train(
    model: Annotated[str, typer.Option(help=MODELS.choices())],
    data: Annotated[list[Path], typer.Option(help="training folder (semmap simulate output, or images/ + labels/ "
                                                  "[+ depth/]) or a folder of them; repeat for several")],
    out: Annotated[Path, typer.Option("--out", "-o", help="run folder: checkpoints, logs, curve, best.pt")],
    val: Annotated[list[Path] | None, typer.Option(help="validation folder (or folder of them); default: every "
                                                        "10th training image")] = None,
    epochs: Annotated[float, typer.Option(help="passes over the training images")] = 12.0,
    iterations: Annotated[int | None, typer.Option(help="SGD steps (overrides --epochs)")] = None,
    batch: Annotated[int, typer.Option(help="images per step")] = 8,
    lr: Annotated[float, typer.Option(help="initial learning rate (poly decay, power 0.9)")] = 0.01,
    input_size: Annotated[str, typer.Option(help="training input WIDTHxHEIGHT (images are resized to it)")
                          ] = "160x120",
    width: Annotated[float, typer.Option(help="width multiplier (1 = the papers' full size)")] = 0.25,
    resnet_depth: Annotated[int, typer.Option(help="ResNet depth 18 | 34 | 50 (fcn, pspnet, cbam-pspnet)")] = 18,
    backbone: Annotated[str, typer.Option(help="backbone: resnet | vgg16 (fcn) | espnetv2-s1 | espnetv2-s2 (every "
                                               "model; set by --init)")] = "resnet",
    init: Annotated[str | None, typer.Option(help="pretrained start: espnetv2-pascal[-s1|-s2] (ESPNetv2 encoder, "
                                                  "weights/espnetv2) | torchvision:resnet18|34|50|vgg16 "
                                                  "(downloads ImageNet weights) | NET.pt (fine-tune semmap's own "
                                                  "weights, e.g. weights/fcn.pt)")] = None,
    device: Annotated[str, typer.Option(help="cpu | cuda")] = "cpu",
    resume: Annotated[bool, typer.Option("--resume", help="continue the run in --out from its last checkpoint")
                      ] = False,
    seed: Annotated[int, typer.Option(help="seed of initialisation, image order and augmentation")] = 0,
    threads: Annotated[int | None, typer.Option(help="CPU threads for PyTorch")] = None,
    eval_every: Annotated[int, typer.Option(help="validate, log and checkpoint every N steps")] = 100,
    class_map: Annotated[Path | None, typer.Option(help="JSON mapping the data's class ids to the label set")
                         ] = None,
    labelset: Annotated[Path | None, typer.Option(help="labelset.json of the classes to train (default: the "
                                                       "data's)")] = None,
    depth_scale: Annotated[float | None, typer.Option(help="depth PNG units per metre (default: 5000 for "
                                                           "simulate/TUM folders, 1000 for plain folders)")] = None,
    augment: Annotated[bool, typer.Option("--augment/--no-augment", help="flips, scale and colour jitter")] = True,
    sensor_augment: Annotated[bool, typer.Option("--sensor-augment", help="also what a real camera does: wider zoom, "
                                                 "white balance, exposure, blur, noise; depth noise, scale error and "
                                                 "holes (for networks that meet real frames)")] = False,
    memory_budget: MemoryBudget = None,
) -> None:
    """Train a segmentation network (median-frequency weighted cross entropy, SGD with poly learning rate) and
    keep the best checkpoint by validation mIoU (RUN_DIR/best.pt, usable as --weights)."""
    setup_logging(False)
    budget(memory_budget)
    from semmap.train.trainer import Trainer, TrainSettings

    size = parse_size(input_size)
    if not isinstance(size, tuple):
        raise SemmapError(f"--input-size must be WIDTHxHEIGHT, got {input_size!r}")
    settings = TrainSettings(model=model, data=tuple(data), out=out, val=tuple(val or ()), epochs=epochs,
                             iterations=iterations, batch=batch, lr=lr, input_size=size, width=width,
                             depth=resnet_depth, backbone=backbone, device=device, seed=seed, threads=threads,
                             eval_every=eval_every, class_map=class_map, label_set=labelset,
                             depth_scale=depth_scale, augment=augment, sensor_augment=sensor_augment, init=init)
    trainer = Trainer(settings, resume=resume)
    if trainer.init_summary is not None:
        stderr_console().print(trainer.init_summary.text(), markup=False, highlight=False)
    stderr_console().print(f"{trainer.spec.describe()}: {len(trainer.train_set)} training and {len(trainer.val_set)} "
                     f"validation images at {size[0]}x{size[1]}, {trainer.total} steps of {batch}")
    with _TrainProgress(trainer.total, trainer.iteration) as progress:
        try:
            result = trainer.run(progress=progress)
        except KeyboardInterrupt:
            print(f"semmap: interrupted; continue with the same command and --resume ({out}/last.pt)",
                  file=sys.stderr)
            raise SystemExit(130) from None
    best = f"{result.best} (val mIoU {result.best_miou:.3f})" if result.best else "none"
    stderr_console().print(f"done: {result.iterations} steps; best {best}; final {result.final}")


class _TrainProgress:
    """A rich progress bar showing the step, the latest training loss and validation mIoU."""

    def __init__(self, total: int, done: int) -> None:
        self.total, self.done = total, done

    def __enter__(self):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._progress = Progress(TextColumn("[bold]training"), BarColumn(), MofNCompleteColumn(),
                                  TextColumn("{task.fields[info]}"), TimeRemainingColumn(), console=stderr_console())
        self._progress.__enter__()
        task = self._progress.add_task("training", total=self.total, completed=self.done, info="")

        def update(i: int, n: int, row: dict) -> None:
            info = f"loss {row['train_loss']:.3f}  val mIoU {row['val_miou']:.3f}" if row else ""
            self._progress.update(task, completed=i, total=n, info=info)

        return update

    def __exit__(self, *exc):
        return self._progress.__exit__(*exc)
