"""The training family: ``semmap train`` (a segmentation network trained on simulated or labelled images) and
``semmap adapt`` (a finished run's map teaches the network that built it)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from semmap.cli.options import Json, MemoryBudget, budget, parse_size
from semmap.cli.terminal import interruptible, print_table, progress_bar, setup_logging, stderr_console, summary_out
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


def adapt(
    run_dir: Annotated[Path, typer.Argument(help="a finished semmap run folder (its config.json, map and "
                                                 "trajectory.txt), mapped with one of semmap's networks")],
    out: Annotated[Path, typer.Option("--out", "-o", help="folder: best.pt (for --weights), manifest.json, "
                                                          "report.md, curve.png, pseudo_labels.png")],
    steps: Annotated[int, typer.Option(help="SGD steps")] = 300,
    batch: Annotated[int, typer.Option(help="images per step (pseudo-labelled and replayed)")] = 8,
    lr: Annotated[float, typer.Option(help="initial learning rate (poly decay)")] = 0.01,
    replay_share: Annotated[float, typer.Option(help="share of each batch from the network's original training "
                                                     "data (0: none)")] = 0.5,
    replay: Annotated[list[Path] | None, typer.Option(help="training folder(s) to replay (default: the scenes the "
                                                           "weights or weights/manifest.json record)")] = None,
    min_confidence: Annotated[float, typer.Option(help="a pixel teaches only where the map's class has at least "
                                                       "this probability")] = 0.5,
    min_views: Annotated[int, typer.Option(help="... and at least this many frames saw its voxel")] = 3,
    network_confidence: Annotated[float, typer.Option(help="... and the network is not this sure of another "
                                                           "class (1: never vetoes)")] = 0.7,
    every: Annotated[int, typer.Option(help="pseudo-label every k-th mapped frame")] = 1,
    eval_every: Annotated[int, typer.Option(help="evaluate, log and checkpoint every N steps")] = 50,
    seed: Annotated[int, typer.Option(help="seed of image order and augmentation")] = 0,
    threads: Annotated[int | None, typer.Option(help="CPU threads for PyTorch")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="continue the adaptation in --out from its last "
                                                          "checkpoint")] = False,
    as_json: Json = False,
    memory_budget: MemoryBudget = None,
) -> None:
    """Fine-tune a run's network on its own map: the map's class at each pixel's 3D point of every frame it used,
    where the map is sure, as labels (no ground truth needed); replays some original training data so it does not
    forget; recalibrates. Reuse the result with semmap run --segmenter NAME --weights OUT/best.pt."""
    setup_logging(False)
    budget(memory_budget)
    from semmap.train.adapt import AdaptSettings
    from semmap.train.pseudo_labels import MaskSettings

    masks = MaskSettings(min_confidence=min_confidence, min_views=min_views,
                         network_confidence=None if network_confidence >= 1 else network_confidence)
    settings = AdaptSettings(out=out, steps=steps, batch=batch, lr=lr, replay_share=replay_share, every=every,
                             eval_every=eval_every, seed=seed, threads=threads, masks=masks,
                             replay_folders=tuple(replay or ()))
    try:
        result = adapt_with_progress(run_dir, settings, resume, command=" ".join(["semmap", "adapt", *sys.argv[2:]]))
    except KeyboardInterrupt:
        print(f"semmap: interrupted; continue with the same command and --resume ({out}/last.pt)", file=sys.stderr)
        raise SystemExit(130) from None
    summary_out(result.report, as_json, f"semmap adapt: {run_dir} -> {result.weights}", adapt_rows(result.report))


def adapt_with_progress(run_dir: Path, settings, resume: bool, *, command: str = ""):
    """``semmap adapt``'s library call behind a progress bar per stage (counting views, pseudo-labels, adapting)."""
    from semmap.run.adapt import adapt_run

    with _StageProgress() as progress:
        return adapt_run(run_dir, settings, resume=resume, progress=progress, command=command)


def adapt_rows(report: dict) -> list[tuple[str, str]]:
    """The adaptation's main numbers for the summary table."""
    p, start, chosen = report["pseudo_labels"], report["start"], report["chosen"]

    def move(key: str) -> str:
        return "-" if start.get(key) is None else f"{start[key]:.3f} -> {chosen.get(key, start[key]):.3f}"

    rows = [("network", report["network"]), ("frames", f"{report['frames']['train']} trained on, "
                                                         f"{report['frames']['holdout']} held out"),
            ("pseudo-label coverage", f"{p['coverage']:.1%} of the pixels with a depth")]
    if "accuracy" in p:
        rows.append(("pseudo-labels vs truth", f"accuracy {p['accuracy']:.3f}, MIoU {p['miou']:.3f} (network on "
                                               f"the same pixels {p.get('network_accuracy', 0):.3f}, "
                                               f"{p.get('network_miou', 0):.3f})"))
    rows += [("replay", f"{report['replay']['images']} images ({report['replay']['source']})"),
             ("kept", f"step {report['best'].get('step')} of {report['steps']}"),
             ("held-out MIoU vs the map", move("holdout_pseudo_miou")),
             ("validation MIoU (forgetting)", move("val_miou"))]
    if start.get("holdout_truth_miou") is not None:
        rows.append(("held-out MIoU vs truth", move("holdout_truth_miou")))
    rows += [("temperature", f"{report['calibration']['temperature']:.3f}"),
             ("CPU time", f"{report['cpu_minutes']:.1f} min"), ("adapted weights", report["files"]["weights"])]
    return rows


class _StageProgress:
    """A rich progress bar per stage of ``progress(stage, i, n)`` calls (views, pseudo-labels, adapting)."""

    def __enter__(self):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                  TimeRemainingColumn(), console=stderr_console())
        self._progress.__enter__()
        tasks: dict[str, int] = {}

        def update(stage: str, i: int, n: int) -> None:
            if stage not in tasks:
                tasks[stage] = self._progress.add_task(stage, total=n)
            self._progress.update(tasks[stage], completed=i, total=n)

        return update

    def __exit__(self, *exc):
        return self._progress.__exit__(*exc)


def run_adapting(config, rounds: int, steps: int) -> None:
    """``semmap run --adapt``: the loop of mapping and adapting, and its table of rounds."""
    from semmap.run.adapt import run_with_adaptation
    from semmap.runner import run_config
    from semmap.train.adapt import AdaptSettings

    with interruptible():
        result = run_with_adaptation(
            config, rounds, AdaptSettings(out=config.output.out, steps=steps),
            run=lambda c: run_config(c, progress=progress_bar(f"mapping ({c.output.out.name})")),
            adapt=adapt_with_progress)
    rows = [(f"round {r['round']}", f"network {r.get('pixel_miou_network', float('nan')):.3f}, map "
                                    f"{r.get('pixel_miou_map', float('nan')):.3f} (pixel MIoU); "
                                    f"{r['weights'] or 'weights as given'}") for r in result.rows]
    print_table(f"semmap run --adapt: {result.out} (rounds.md)", rows)
