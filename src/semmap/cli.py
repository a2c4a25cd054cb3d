"""The ``semmap`` command line: each command loads, calls one library function and saves.

Known errors (bad input, bad files) print one clear line and exit with code 1; tracebacks are for bugs.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer

from semmap.config import (
    CrfConfig,
    InputConfig,
    MappingConfig,
    ObjectsConfig,
    OutputConfig,
    SemanticsConfig,
    SemanticSource,
)
from semmap.datasets import AUTO, FORMATS
from semmap.errors import SemmapError
from semmap.fusion.crf import CRF_KEYS, parse_crf_params
from semmap.fusion.rules import FusionRule
from semmap.maps.registry import MAPS, own_rules
from semmap.perception.instances.registry import INSTANCE_SOURCES
from semmap.perception.networks.registry import MODELS
from semmap.perception.registry import SEGMENTERS, SegmenterName
from semmap.poses.track import GROUND_TRUTH, TRACKERS, pose_sources_help

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="RGB-D sequences to 3D semantic maps (semantic OctoMap, .ot/.bt/native files, reports).")

_INPUT = "Input"
_MAPPING = "Mapping"
_SEMANTICS = "Semantics"
_OUTPUT = "Output"
_POSES = "Poses"
_OBJECTS = "Objects"
_ROS = "ROS bags"
_MAPS = "Maps and fusion"


#: ``--memory-budget`` of the commands that allocate in proportion to an option (see ``semmap.limits``).
_MemoryBudget = Annotated[str | None, typer.Option(help="refuse options whose memory estimate exceeds this (e.g. "
                                                        "4G; default: SEMMAP_MEMORY_BUDGET, else 75 % of the "
                                                        "available memory)")]


#: ``--json`` of the commands that print a table of their result.
_Json = Annotated[bool, typer.Option("--json", help="print the full result as JSON on stdout instead of the table")]


def _budget(text: str | None) -> None:
    """Apply ``--memory-budget`` for this command."""
    from semmap.limits import set_memory_budget

    set_memory_budget(text)


def _default(section, field: str):
    """The run configuration's default of ``section.field``: the CLI repeats none of them."""
    return section.model_fields[field].default


#: ``--format`` help, ``--semantics`` help and the default ``--maps``, from the registries and the configuration.
_FORMATS = FORMATS.choices((AUTO,))
_SOURCES = " | ".join(s.value for s in SemanticSource)
_RULES = " | ".join(r.value for r in FusionRule)
_DEFAULT_MAPS = ",".join(kind.value for kind in _default(MappingConfig, "maps"))


def _console():
    from rich.console import Console

    return Console(stderr=True)


def _setup_logging(verbose: bool) -> None:
    """Rich log lines on a terminal; plain one-line ``semmap: warning: ...`` messages otherwise (logs, CI)."""
    if sys.stderr.isatty():
        from rich.logging import RichHandler

        handler: logging.Handler = RichHandler(console=_console(), show_time=False, show_path=False, markup=False)
        fmt = "%(message)s"
    else:
        handler = logging.StreamHandler(sys.stderr)
        fmt = "semmap: %(levelname)s: %(message)s"
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format=fmt, handlers=[handler],
                        force=True)
    logging.getLogger("numba").setLevel(logging.WARNING)
    logging.getLogger("numexpr").setLevel(logging.WARNING)  # "NumExpr defaulting to N threads" (via rerun/pandas)


def progress_bar(description: str):
    """A rich progress wrapper ``(iterator, total) -> iterator`` for long loops."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    def wrap(it: Iterator, total: int) -> Iterator:
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[rate]}"), TimeRemainingColumn(), console=_console(),
                      transient=False) as progress:
            task = progress.add_task(description, total=total, rate="")
            import time

            t0 = time.perf_counter()
            for i, item in enumerate(it, 1):
                yield item
                rate = i / max(time.perf_counter() - t0, 1e-9)
                progress.update(task, advance=1, rate=f"{rate:.1f} frames/s")

    return wrap


@app.command()
def run(
    dataset: Annotated[Path, typer.Argument(help="RGB-D sequence: TUM RGB-D or 7-Scenes folder, ROS 1 .bag or ROS 2 "
                                                 "bag folder")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder", rich_help_panel=_OUTPUT)],
    format: Annotated[str, typer.Option(help=_FORMATS, rich_help_panel=_INPUT)] = AUTO,
    labels: Annotated[Path | None, typer.Option(help="folder of label PNGs (class ids) matched to frames by name",
                                                 rich_help_panel=_INPUT)] = None,
    max_frames: Annotated[int | None, typer.Option(help="use at most N frames", rich_help_panel=_INPUT)] = None,
    stride: Annotated[int, typer.Option(help="use every k-th frame",
                                        rich_help_panel=_INPUT)] = _default(InputConfig, "stride"),
    raw_color: Annotated[bool, typer.Option("--raw-color", help="7-Scenes: keep colour as stored instead of "
                                            "registering it onto the depth image", rich_help_panel=_INPUT)] = False,
    strict: Annotated[bool, typer.Option("--strict", help="stop at the first unusable frame (missing or corrupt "
                                         "file, wrong image size, non-finite pose) instead of skipping it",
                                         rich_help_panel=_INPUT)] = False,
    rgb_topic: Annotated[str | None, typer.Option(help="ROS bag: colour image topic", rich_help_panel=_ROS)] = None,
    depth_topic: Annotated[str | None, typer.Option(help="ROS bag: depth image topic", rich_help_panel=_ROS)] = None,
    camera_info_topic: Annotated[str | None, typer.Option(help="ROS bag: CameraInfo topic",
                                                          rich_help_panel=_ROS)] = None,
    pose_topic: Annotated[str | None, typer.Option(help="ROS bag: PoseStamped / Odometry topic (default: /tf)",
                                                   rich_help_panel=_ROS)] = None,
    world_frame: Annotated[str | None, typer.Option(help="ROS bag: /tf world frame", rich_help_panel=_ROS)] = None,
    camera_frame: Annotated[str | None, typer.Option(help="ROS bag: /tf camera frame", rich_help_panel=_ROS)] = None,
    resolution: Annotated[float, typer.Option(help="finest voxel size (m)",
                                              rich_help_panel=_MAPPING)] = _default(MappingConfig, "resolution"),
    min_depth: Annotated[float, typer.Option(help="ignore depth below (m)",
                                             rich_help_panel=_MAPPING)] = _default(MappingConfig, "min_depth"),
    max_depth: Annotated[float, typer.Option(help="ignore depth above (m)",
                                             rich_help_panel=_MAPPING)] = _default(MappingConfig, "max_depth"),
    max_range: Annotated[float, typer.Option(help="OctoMap max range (m), -1 = none",
                                             rich_help_panel=_MAPPING)] = _default(MappingConfig, "max_range"),
    pixel_stride: Annotated[int, typer.Option(help="use every k-th pixel row/column",
                                              rich_help_panel=_MAPPING)] = _default(MappingConfig, "pixel_stride"),
    semantics: Annotated[str, typer.Option(help=_SOURCES,
                                           rich_help_panel=_SEMANTICS)] = _default(SemanticsConfig, "source").value,
    label_confidence: Annotated[float, typer.Option(help="confidence of hard labels", rich_help_panel=_SEMANTICS)
                                ] = _default(SemanticsConfig, "label_confidence"),
    temperature: Annotated[float, typer.Option(help="fuse softmax(logits / T) of the segmenter's classes: > 1 softens "
                                                    "over-confident probabilities, < 1 sharpens, 1 = as given",
                                               rich_help_panel=_SEMANTICS)] = _default(SemanticsConfig,
                                                                                       "temperature"),
    lam: Annotated[float, typer.Option("--lambda", help="penalty λ of the top-k fusion (Algorithm 1)",
                                       rich_help_panel=_SEMANTICS)] = _default(SemanticsConfig, "lam"),
    segmenter: Annotated[str | None, typer.Option(help=f"{SEGMENTERS.choices()} (onnx:MODEL.onnx, hf:MODEL_ID; "
                                                       "default: from --semantics)",
                                                  rich_help_panel=_SEMANTICS)] = None,
    weights: Annotated[Path | None, typer.Option(help="network weights (espnetv2; semmap's networks default to the "
                                                 "shipped weights/), or the predictions folder (precomputed)",
                                                 rich_help_panel=_SEMANTICS)] = None,
    trust_weights: Annotated[bool, typer.Option("--trust-weights", help="use shipped weights whose sha256 differs "
                                                "from weights/manifest.json (with a warning)",
                                                rich_help_panel=_SEMANTICS)] = False,
    segmenter_config: Annotated[Path | None, typer.Option(help="JSON sidecar of --segmenter onnx:MODEL.onnx "
                                                          "(default: MODEL.json beside it)",
                                                          rich_help_panel=_SEMANTICS)] = None,
    class_map: Annotated[Path | None, typer.Option(help="JSON mapping of an onnx:/hf: model's classes to the map's "
                                                   "labels (or a shipped one: ade20k-150, nyu40, coco-panoptic-133)",
                                                   rich_help_panel=_SEMANTICS)] = None,
    calibration: Annotated[bool, typer.Option("--calibration/--no-calibration",
                                              help="scale a trained network's probabilities by the temperature "
                                                   "fitted on its validation scenes (stored with its weights)",
                                              rich_help_panel=_SEMANTICS)] = True,
    segment_every: Annotated[int, typer.Option(help="segment every k-th frame (others add geometry and colour)",
                                               rich_help_panel=_SEMANTICS)] = _default(SemanticsConfig,
                                                                                       "segment_every"),
    keyframes: Annotated[bool, typer.Option("--keyframes", help="segment only frames where the camera moved "
                                            "10 cm or turned 10° since the last segmented one",
                                            rich_help_panel=_SEMANTICS)] = False,
    batch_size: Annotated[int, typer.Option(help="frames per network batch",
                                            rich_help_panel=_SEMANTICS)] = _default(SemanticsConfig, "batch_size"),
    backend: Annotated[str, typer.Option(help="torch | onnx: network runtime",
                                         rich_help_panel=_SEMANTICS)] = _default(SemanticsConfig, "backend"),
    input_size: Annotated[str | None, typer.Option(help="network input: WIDTHxHEIGHT, or a short side N "
                                                   "keeping the aspect ratio (espnetv2 default: 320)",
                                                   rich_help_panel=_SEMANTICS)
                          ] = None,
    poses: Annotated[str, typer.Option(help=pose_sources_help(), rich_help_panel=_POSES)] = GROUND_TRUTH,
    online: Annotated[bool, typer.Option("--online", help="map each frame as soon as the tracker has its pose, "
                                         "segmenting beside tracking (default: track the whole sequence first)",
                                         rich_help_panel=_POSES)] = False,
    rate: Annotated[float | None, typer.Option(help="with --online: replay the frames at this many per second, as "
                                                    "a live camera delivers them (latency counts from each "
                                                    "frame's due time)", rich_help_panel=_POSES)] = None,
    color_mode: Annotated[str, typer.Option(help="class | rgb: voxel colour in map.ot",
                                            rich_help_panel=_OUTPUT)] = _default(OutputConfig, "color_mode").value,
    rerun: Annotated[Path | None, typer.Option(help="log images, poses and the growing map to this rerun "
                                               "recording (.rrd)", rich_help_panel=_OUTPUT)] = None,
    rerun_spawn: Annotated[bool, typer.Option("--rerun-spawn", help="watch the map grow in a rerun viewer",
                                              rich_help_panel=_OUTPUT)] = False,
    rerun_map_every: Annotated[int, typer.Option(help="frames between two logs of the whole map to rerun",
                                                 rich_help_panel=_OUTPUT)] = _default(OutputConfig, "rerun_map_every"),
    cloud: Annotated[bool, typer.Option("--cloud/--no-cloud", help="write cloud.ply, the dense coloured cloud of every "
                                        "frame's points (one per --point-resolution cell) the report's storage table "
                                        "compares the maps with", rich_help_panel=_OUTPUT)] = True,
    checkpoint_every: Annotated[int, typer.Option(help="save the run's state every N mapped frames (0: never), so "
                                                  "--resume can continue after a crash", rich_help_panel=_OUTPUT)] = 0,
    resume: Annotated[bool, typer.Option("--resume", help="continue a run that was killed, from its last checkpoint "
                                         "(same options as the first time)", rich_help_panel=_OUTPUT)] = False,
    continue_from: Annotated[Path | None, typer.Option("--continue", help="go on from a finished run's maps (its "
                                                       "folder or map file): the recording is localized in them and "
                                                       "mapped into their frame", rich_help_panel=_OUTPUT)] = None,
    maps: Annotated[str, typer.Option(help=f"maps built side by side, comma-separated, the first is the primary: "
                                           f"{MAPS.choices()}", rich_help_panel=_MAPS)] = _DEFAULT_MAPS,
    fusion: Annotated[str | None, typer.Option(help=f"label fusion for every map: {_RULES} (default: each map's "
                                                    f"own: {own_rules()})", rich_help_panel=_MAPS)] = None,
    state_dtype: Annotated[str | None, typer.Option(help="float16 | float32: per-class numbers of the voxel grid and "
                                                         "point map (default float32 / float16)",
                                                    rich_help_panel=_MAPS)] = None,
    free_space: Annotated[bool, typer.Option("--free-space", help="voxel grid: ray-cast free space too",
                                             rich_help_panel=_MAPS)] = False,
    point_resolution: Annotated[float, typer.Option(help="filter cell of the point map (m)", rich_help_panel=_MAPS)
                                ] = _default(MappingConfig, "point_resolution"),
    tsdf_voxel: Annotated[float | None, typer.Option(help="voxel of the TSDF (m; default: --resolution)",
                                                     rich_help_panel=_MAPS)] = None,
    tsdf_truncation: Annotated[float, typer.Option(help="TSDF truncation distance in voxels",
                                                   rich_help_panel=_MAPS)] = _default(MappingConfig,
                                                                                      "tsdf_truncation"),
    decay: Annotated[float, typer.Option(help="share of log-odds an OctoMap cell not observed in a frame loses "
                                              "towards unknown (0: none)", rich_help_panel=_MAPS)
                     ] = _default(MappingConfig, "decay"),
    dynamic: Annotated[str, typer.Option(help="dynamic classes, comma-separated (the whole list, e.g. person,chair; "
                                              "none for no class): their points clear free space along their "
                                              "rays but never occupy a voxel", rich_help_panel=_MAPS)
                       ] = ",".join(_default(MappingConfig, "dynamic")),
    top_k: Annotated[int, typer.Option(help="classes per top-k set (1..8): the segmenter's sets and topk fusion",
                                       rich_help_panel=_MAPS)] = _default(SemanticsConfig, "k"),
    max_confidence: Annotated[float, typer.Option(help="cap on a voxel's top confidence (topk, max)",
                                                  rich_help_panel=_MAPS)] = _default(SemanticsConfig,
                                                                                     "max_confidence"),
    class_prior: Annotated[Path | None, typer.Option(help="bayes-prior: JSON {class name: frequency} "
                                                     "(default uniform)", rich_help_panel=_MAPS)] = None,
    crf: Annotated[bool, typer.Option("--crf", help="refine every map with a 3D dense CRF after mapping",
                                      rich_help_panel=_MAPS)] = False,
    crf_every: Annotated[int, typer.Option(help="with --crf, also refine every N keyframes while mapping",
                                           rich_help_panel=_MAPS)] = _default(CrfConfig, "every"),
    crf_params: Annotated[str | None, typer.Option(help="with --crf, its kernels as key=value,... (keys: "
                                                        f"{', '.join(CRF_KEYS)}; 'semanticfusion' for "
                                                        "SemanticFusion's values; docs/EXPERIMENTS.md)",
                                                   rich_help_panel=_MAPS)] = None,
    instances: Annotated[str | None, typer.Option(help=f"{INSTANCE_SOURCES.choices()}: also build the object map "
                                                   "(objects.json, objects.ply)", rich_help_panel=_OBJECTS)] = None,
    instance_weights: Annotated[Path | None, typer.Option(help="Mask R-CNN weights (--instances maskrcnn)",
                                                          rich_help_panel=_OBJECTS)] = None,
    instance_errors: Annotated[str, typer.Option(help="oracle instances' errors: exact | maskrcnn-like | noisy",
                                                 rich_help_panel=_OBJECTS)] = _default(ObjectsConfig, "errors"),
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="debug logging")] = False,
    memory_budget: _MemoryBudget = None,
) -> None:
    """Map an RGB-D sequence: writes map.ot, map.bt, map.semmap (and voxelgrid.* / points.* for --maps,
    objects.json / objects.ply for --instances), cloud.ply (the dense coloured cloud; --no-cloud: none), preview.png,
    trajectory.txt, report.json, report.md and config.json."""
    _setup_logging(verbose)
    _budget(memory_budget)
    from semmap.config import (
        CrfConfig,
        InputConfig,
        LoopMode,
        MappingConfig,
        ObjectsConfig,
        OnlineConfig,
        OutputConfig,
        PosesConfig,
        RosConfig,
        RunConfig,
        SemanticsConfig,
    )
    from semmap.maps.registry import map_kind
    from semmap.runner import run_config

    kinds = tuple(map_kind(name.strip()) for name in maps.split(",") if name.strip())

    config = _validated(lambda: RunConfig(
        input=InputConfig(dataset=dataset, format=format, labels=labels, stride=stride, max_frames=max_frames,
                          raw_color=raw_color, strict=strict,
                          ros=RosConfig(rgb_topic=rgb_topic, depth_topic=depth_topic,
                                        camera_info_topic=camera_info_topic, pose_topic=pose_topic,
                                        world_frame=world_frame, camera_frame=camera_frame)),
        mapping=MappingConfig(resolution=resolution, min_depth=min_depth, max_depth=max_depth,
                              max_range=max_range, pixel_stride=pixel_stride, maps=kinds, state_dtype=state_dtype,
                              free_space=free_space, point_resolution=point_resolution, tsdf_voxel=tsdf_voxel,
                              tsdf_truncation=tsdf_truncation, dynamic=dynamic, decay=decay),
        semantics=SemanticsConfig(source=semantics, label_confidence=label_confidence, lam=lam, k=top_k,
                                  temperature=temperature,
                                  max_confidence=max_confidence, segmenter=segmenter,
                                  weights=weights, trust_weights=trust_weights, segmenter_config=segmenter_config,
                                  class_map=class_map, calibration=calibration, segment_every=segment_every,
                                  keyframes=keyframes,
                                  batch_size=batch_size, backend=backend, input_size=_size(input_size),
                                  fusion=fusion, class_prior=class_prior),
        poses=PosesConfig(source=poses),
        mode=LoopMode.ONLINE if online else LoopMode.OFFLINE,
        online=OnlineConfig(rate=rate),
        crf=CrfConfig(enabled=crf, every=crf_every, **parse_crf_params(crf_params)),
        objects=ObjectsConfig(instances=instances, weights=instance_weights, errors=instance_errors),
        output=OutputConfig(out=out, color_mode=_color_mode(color_mode), rerun=rerun, rerun_spawn=rerun_spawn,
                            rerun_map_every=rerun_map_every, cloud=cloud),
    ))
    with _interruptible():
        result = run_config(config, progress=progress_bar("mapping"),
                            track_progress=progress_bar(f"tracking ({poses})"), checkpoint_every=checkpoint_every,
                            resume=resume, continue_from=continue_from)
    try:
        _print_summary(result.report, result.out_dir)
    except KeyboardInterrupt:  # the outputs are complete by now: say so, and it is a success
        print(f"semmap: Ctrl-C after the run had finished; its outputs in {result.out_dir} are complete",
              file=sys.stderr)


@contextlib.contextmanager
def _interruptible():
    """Ctrl-C: one line saying after which frame the run stopped and what was kept, and exit code 130 (typer would
    exit 130 silently, and a Ctrl-C inside a numba kernel would show a SystemError)."""
    from semmap.interrupt import RunInterrupted

    try:
        yield
    except RunInterrupted as exc:
        print(f"semmap: {exc}", file=sys.stderr)
        raise typer.Exit(130) from None
    except KeyboardInterrupt:
        print("semmap: interrupted", file=sys.stderr)
        raise typer.Exit(130) from None
    except SystemError as exc:
        if not isinstance(exc.__cause__ or exc.__context__, KeyboardInterrupt):
            raise
        print("semmap: interrupted", file=sys.stderr)
        raise typer.Exit(130) from None


def _color_mode(value: str):
    """``--color-mode`` as the config's enum, or one clear line."""
    from semmap.config import ColorMode

    try:
        return ColorMode(value)
    except ValueError:
        raise SemmapError(f"--color-mode must be one of {[m.value for m in ColorMode]}, got {value!r}") from None


def _size(text: str | None) -> tuple[int, int] | int | None:
    """``"512x384"`` -> (512, 384); ``"384"`` -> 384 (the short side)."""
    from semmap.perception.network import parse_input_size

    return parse_input_size(text)


def _validated(make, source: Path | None = None):
    """``make()``, its first validation error as one line (naming ``source``, the file the values came from)."""
    from pydantic import ValidationError

    try:
        return make()
    except SemmapError as exc:  # a limits check inside a validator: say which file the value came from
        if source is None or str(source) in str(exc):
            raise
        raise SemmapError(f"{source}: {exc}") from None
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        msg = str(first["msg"]).removeprefix("Value error, ")
        if source is not None:
            raise SemmapError(f"{source}: {f'field {where}: ' if where else ''}{msg}"
                              f"{'' if where else ' (expected a JSON object like a run folder config.json)'}"
                              ) from None
        if not where:  # a rule across options
            raise SemmapError(msg) from None
        raise SemmapError(f"invalid {_option_of(exc.title, first['loc'])}: {msg}") from None


#: configuration fields whose command-line option is not ``--`` + the field's name (section.field -> option)
_FIELD_OPTIONS = {
    "semantics.source": "--semantics", "semantics.k": "--top-k", "semantics.lam": "--lambda",
    "poses.source": "--poses", "input.dataset": "dataset argument", "output.out": "--out",
    "crf.enabled": "--crf", "crf.every": "--crf-every", "objects.weights": "--instance-weights",
    "objects.errors": "--instance-errors",
}


def _option_of(model_title: str, loc: tuple) -> str:
    """The command-line option a configuration field came from (``SemanticsConfig`` + ``source`` -> ``--semantics``)."""
    from semmap import config as config_module

    model = getattr(config_module, str(model_title), None)
    section = str(getattr(model, "section", "") or "")
    field = str(loc[-1]) if not isinstance(loc[-1], int) else str(loc[-2] if len(loc) > 1 else loc[-1])
    key = f"{section.rsplit('.', 1)[-1]}.{field}" if section else ".".join(str(p) for p in loc)
    return _FIELD_OPTIONS.get(key) or f"--{field.replace('_', '-')}"


def _print_table(title: str, rows: list[tuple[str, str]]) -> None:
    """The summary table every command prints (on stderr, beside its progress bars; ``--json`` is for scripts)."""
    from rich.table import Table

    t = Table(title=title, show_header=False)
    for key, value in rows:
        t.add_row(key, value)
    _console().print(t)


def _print_summary(report: dict, out_dir: Path) -> None:
    rows = [(key, str(report[key])) for key in ("frames_used", "frames_skipped", "occupied_voxels", "free_voxels",
                                                "occupied_leaves", "free_leaves", "bytes_in_memory", "semantics",
                                                "miou_3d",
                                                *(k for k in report if k.endswith("_miou_2d")), "frames_segmented",
                                                "pixel_miou_map", "pixel_miou_network", "pixel_coverage")
            if key in report]
    if "trajectory_vs_ground_truth" in report:
        ate = report["trajectory_vs_ground_truth"]["ate_rmse_m"]
        rows.append(("ATE of the poses used", f"{100 * ate:.2f} cm"))
    if "continued" in report:
        c = report["continued"]
        rows.append(("continued from", f"{c['prior']}: localized after {c['converged_after_frames']} frames, ICP "
                                       f"residual {100 * c['icp'].get('rms_residual_m', 0.0):.2f} cm"))
    if "online" in report:
        o = report["online"]
        rows.append(("online", f"{o['fps']:.1f} frames/s, latency {o['latency_ms']['median']:.0f} ms (median), "
                               f"drift left in {o['drift_left_in']['max_mm']:.1f} mm (max)"))
    top = list(report.get("voxels_per_class", {}).items())[:8]
    if top:
        rows.append(("voxels per class", ", ".join(f"{name} {n:,}" for name, n in top)))
    rows += [(f"size of {name}", f"{size:,} B") for name, size in report.get("bytes_on_disk", {}).items()]
    rows.append(("ms per frame", f"{report['ms_per_frame']['total']:.1f}"))
    _print_table(f"semmap: {out_dir}", rows)


def _summary_out(summary: dict, as_json: bool, title: str, rows: list[tuple[str, str]]) -> None:
    """A command's result: the full JSON on stdout with ``--json``, else the table of its main numbers."""
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
    else:
        _print_table(title, rows)


def _cm(metres: float | None) -> str:
    return "-" if metres is None else f"{100 * metres:.2f} cm"


@app.command()
def simulate(
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder (TUM RGB-D layout + ground truth)")],
    scene_seed: Annotated[int, typer.Option(help="scene generator seed")] = 0,
    kind: Annotated[str, typer.Option(help="office | kitchen | living_room | bedroom")] = "office",
    size: Annotated[str, typer.Option(help="small | medium | large")] = "medium",
    trajectory: Annotated[str, typer.Option(help="desk | loop | orbit | walk")] = "loop",
    frames: Annotated[int, typer.Option(help="frames to render (30 per second)")] = 300,
    noise: Annotated[bool, typer.Option("--noise/--no-noise", help="Kinect-like depth noise")] = True,
    image_size: Annotated[str | None, typer.Option(help="store frames reduced to WIDTHxHEIGHT (e.g. 160x120 "
                                                   "training data for semmap train); rendered at 640x480")] = None,
    symmetric: Annotated[bool, typer.Option("--symmetric", help="one room whose geometry maps onto itself under a "
                                            "180° turn, its halves told apart only by their classes")] = False,
    trajectory_seed: Annotated[int | None, typer.Option(help="seed of the camera path (default: the scene seed); "
                                                        "another seed gives another path through the same scene")
                               ] = None,
    format: Annotated[str | None, typer.Option("--format", help="tum (semmap's own; the default) | scannet (a .sens "
                                               "scan, NYU-40 labels) | replica (NICE-SLAM layout, Semantic-NeRF "
                                               "labels)")] = None,
    changes: Annotated[int, typer.Option(help="the same scene a while later: N objects moved, removed or added "
                                              "(in turn); changes.json records them (for semmap diff)")] = 0,
    changes_seed: Annotated[int, typer.Option(help="seed of which objects change and where")] = 1,
    people: Annotated[int, typer.Option(help="people walking to and fro through the scene (labelled person; not "
                                             "in the 3D ground truth: semmap run keeps them out of the map)")] = 0,
    realism: Annotated[str, typer.Option(help="how real the sensor looks: clean (exact geometry, light depth noise; "
                                         "the default) | kinect (a Kinect v1 calibrated on 7-Scenes: depth, colour "
                                         "camera, hand-held motion) | hard (the same on a worse day); scene.json "
                                         "records it")] = "clean",
    memory_budget: _MemoryBudget = None,
) -> None:
    """Render a procedural indoor scene to a TUM RGB-D folder with labels, instances, objects and scene.json."""
    _setup_logging(False)
    _budget(memory_budget)
    from semmap.sim.export import LAYOUTS, check_sequence_out, simulate_sequence

    stored = _size(image_size)
    if isinstance(stored, int):
        raise SemmapError(f"--image-size must be WIDTHxHEIGHT, got {image_size!r}")
    check_sequence_out(out)  # (before the progress bar: a refusal is one line)
    with _interruptible(), _ProgressCallback("rendering", frames) as callback:
        root = simulate_sequence(out, scene_seed=scene_seed, kind=kind, size=size, trajectory=trajectory,
                                 frames=frames, noise=noise, progress=callback, image_size=stored, symmetric=symmetric,
                                 trajectory_seed=trajectory_seed, layout=format or LAYOUTS[0],
                                 changes=changes, changes_seed=changes_seed, people=people, realism=realism)
    _console().print(f"wrote {frames} frames to {root} (map it with: semmap run {root} --out OUT)")


class _ProgressCallback:
    """A rich progress bar driven by ``callback(i, n)`` calls (for library functions that report progress)."""

    def __init__(self, description: str, total: int) -> None:
        self.description, self.total = description, total

    def __enter__(self):
        self._progress = None
        return self._update

    def _update(self, i: int, n: int) -> None:
        """Start the bar on the first report (a refusal before any work shows only its one line)."""
        if self._progress is None:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self._progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                      TimeRemainingColumn(), console=_console())
            self._progress.__enter__()
            self._task = self._progress.add_task(self.description, total=self.total)
        self._progress.update(self._task, completed=i, total=n)

    def __exit__(self, *exc):
        return None if self._progress is None else self._progress.__exit__(*exc)


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")] = Path("outputs/demo"),
    frames: Annotated[int, typer.Option(help="frames of the default trajectory")] = 300,
    resolution: Annotated[float, typer.Option(help="finest voxel size (m)")] = _default(MappingConfig, "resolution"),
    scene_seed: Annotated[int, typer.Option(help="scene generator seed")] = 0,
    rerun: Annotated[Path | None, typer.Option(help="also log the run to this rerun recording (.rrd)")] = None,
    semantics: Annotated[str, typer.Option(help="network (the shipped network named in weights/manifest.json, "
                                                "ONNX Runtime) | oracle (the cnn-like error model)")] = "network",
    trust_weights: Annotated[bool, typer.Option("--trust-weights", help="use shipped weights whose sha256 differs "
                                                "from weights/manifest.json (with a warning)")] = False,
) -> None:
    """Simulate the default scene, map it with ground-truth poses and the shipped segmentation network (or the
    cnn-like oracle), and write the outputs of `semmap run` plus report.md with 3D accuracy against ground truth."""
    _setup_logging(False)
    from semmap.runner import run_demo

    if semantics not in ("network", SegmenterName.ORACLE):
        raise SemmapError(f"--semantics must be network or oracle, got {semantics!r}")
    with _interruptible():
        result = _validated(lambda: run_demo(out=out, frames=frames, resolution=resolution, scene_seed=scene_seed,
                                             rerun=rerun, oracle=semantics == SegmenterName.ORACLE,
                                             trust_weights=trust_weights, progress=progress_bar("simulate + map")))
    _print_summary(result.report, result.out_dir)


@app.command()
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
                                                  "../shared/weights/espnetv2) | torchvision:resnet18|34|50|vgg16 "
                                                  "(downloads ImageNet weights)")] = None,
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
    memory_budget: _MemoryBudget = None,
) -> None:
    """Train a segmentation network (median-frequency weighted cross entropy, SGD with poly learning rate) and
    keep the best checkpoint by validation mIoU (RUN_DIR/best.pt, usable as --weights)."""
    _setup_logging(False)
    _budget(memory_budget)
    from semmap.train.trainer import Trainer, TrainSettings

    size = _size(input_size)
    if not isinstance(size, tuple):
        raise SemmapError(f"--input-size must be WIDTHxHEIGHT, got {input_size!r}")
    settings = TrainSettings(model=model, data=tuple(data), out=out, val=tuple(val or ()), epochs=epochs,
                             iterations=iterations, batch=batch, lr=lr, input_size=size, width=width,
                             depth=resnet_depth, backbone=backbone, device=device, seed=seed, threads=threads,
                             eval_every=eval_every, class_map=class_map, label_set=labelset,
                             depth_scale=depth_scale, augment=augment, init=init)
    trainer = Trainer(settings, resume=resume)
    if trainer.init_summary is not None:
        _console().print(trainer.init_summary.text(), markup=False, highlight=False)
    _console().print(f"{trainer.spec.describe()}: {len(trainer.train_set)} training and {len(trainer.val_set)} "
                     f"validation images at {size[0]}x{size[1]}, {trainer.total} steps of {batch}")
    with _TrainProgress(trainer.total, trainer.iteration) as progress:
        try:
            result = trainer.run(progress=progress)
        except KeyboardInterrupt:
            print(f"semmap: interrupted; continue with the same command and --resume ({out}/last.pt)",
                  file=sys.stderr)
            raise SystemExit(130) from None
    best = f"{result.best} (val mIoU {result.best_miou:.3f})" if result.best else "none"
    _console().print(f"done: {result.iterations} steps; best {best}; final {result.final}")


class _TrainProgress:
    """A rich progress bar showing the step, the latest training loss and validation mIoU."""

    def __init__(self, total: int, done: int) -> None:
        self.total, self.done = total, done

    def __enter__(self):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._progress = Progress(TextColumn("[bold]training"), BarColumn(), MofNCompleteColumn(),
                                  TextColumn("{task.fields[info]}"), TimeRemainingColumn(), console=_console())
        self._progress.__enter__()
        task = self._progress.add_task("training", total=self.total, completed=self.done, info="")

        def update(i: int, n: int, row: dict) -> None:
            info = f"loss {row['train_loss']:.3f}  val mIoU {row['val_miou']:.3f}" if row else ""
            self._progress.update(task, completed=i, total=n, info=info)

        return update

    def __exit__(self, *exc):
        return self._progress.__exit__(*exc)


@app.command()
def track(
    dataset: Annotated[Path, typer.Argument(help="RGB-D sequence folder (TUM RGB-D or 7-Scenes layout)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="trajectory file to write (TUM format)")],
    method: Annotated[str, typer.Option(help=TRACKERS.choices())] = TRACKERS.names[0],
    format: Annotated[str, typer.Option(help=_FORMATS)] = AUTO,
    max_frames: Annotated[int | None, typer.Option(help="use at most N frames")] = None,
    stride: Annotated[int, typer.Option(help="use every k-th frame")] = 1,
    plot: Annotated[Path | None, typer.Option(help="also plot the trajectory (and ground truth) to this PNG")] = None,
    as_json: _Json = False,
) -> None:
    """Estimate the camera trajectory of a sequence and write it in TUM format; scored against the dataset's
    ground truth when it has one."""
    _setup_logging(False)
    from semmap.runner import track_to_file

    with _interruptible():
        summary = track_to_file(dataset, method, out, plot=plot, format=format, stride=stride,
                                max_frames=max_frames, progress=progress_bar(f"tracking ({method})"))
    rows = [("method", method), ("frames tracked", f"{summary['tracked']} of {summary['frames']}"),
            ("ms per frame", f"{summary['ms_per_frame']:.1f}"), ("trajectory", summary["trajectory"])]
    if "ate_rmse_m" in summary:
        rows += [("ATE (SE(3) aligned)", _cm(summary["ate_rmse_m"])), ("RPE per frame", _cm(summary["rpe_trans_m"])),
                 ("Sim(3) scale", _scale(summary["sim3_scale"])), ("poses matched", str(summary["matched"]))]
    else:
        rows.append(("ATE", "not scored (the sequence has no ground truth)"))
    if plot is not None:
        rows.append(("plot", str(plot)))
    _summary_out(summary, as_json, f"semmap track: {dataset}", rows)


@app.command()
def localize(
    map_path: Annotated[Path, typer.Argument(metavar="MAP", help="map.semmap written by semmap run (or its folder)")],
    sequence: Annotated[Path, typer.Argument(metavar="SEQ", help="RGB-D sequence to localize (TUM / 7-Scenes folder)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    model: Annotated[str, typer.Option(help="semantic | geometry | cosine (the paper's score)")] = "semantic",
    particles: Annotated[int, typer.Option(help="number of particles")] = 2000,
    init: Annotated[str, typer.Option(help="global (anywhere in the map) | tracking (around --init-pose or the "
                                           "first frame's ground truth)")] = "global",
    init_pose: Annotated[str | None, typer.Option(help="tracking start: 'tx ty tz qx qy qz qw'")] = None,
    mode: Annotated[str, typer.Option(help="6dof | ground (x, y, yaw; height and tilt known)")] = "6dof",
    motion: Annotated[str, typer.Option(help="odometry (semmap's dense odometry) | gt-noisy (ground truth with "
                                             "drift, experiments) | PATH of a TUM trajectory")] = "odometry",
    motion_noise: Annotated[float, typer.Option(help="gt-noisy: drift as a fraction of each motion")] = 0.05,
    segmenter: Annotated[str, typer.Option(help=f"auto (oracle when the sequence has label images) | none | "
                                                f"{SEGMENTERS.choices()}")] = "auto",
    weights: Annotated[Path | None, typer.Option(help="network weights (espnetv2) or predictions folder "
                                                 "(precomputed)")] = None,
    trust_weights: Annotated[bool, typer.Option("--trust-weights", help="use shipped weights whose sha256 differs "
                                                "from weights/manifest.json (with a warning)")] = False,
    height: Annotated[float | None, typer.Option(help="ground mode: camera height (m); default: from ground "
                                                 "truth")] = None,
    pitch_deg: Annotated[float, typer.Option(help="ground mode with --height: camera pitch (°, down < 0)")] = 0.0,
    roll_deg: Annotated[float, typer.Option(help="ground mode with --height: camera roll (°)")] = 0.0,
    points: Annotated[int, typer.Option(help="points per scan")] = 400,
    stride: Annotated[int, typer.Option(help="use every k-th frame")] = 1,
    max_frames: Annotated[int | None, typer.Option(help="use at most N frames")] = None,
    seed: Annotated[int, typer.Option(help="random seed")] = 0,
    gif: Annotated[bool, typer.Option("--gif", help="also write particles.gif")] = False,
    memory_budget: _MemoryBudget = None,
    as_json: _Json = False,
) -> None:
    """Monte-Carlo localization of a sequence's camera in a prior map: writes localization.txt, localization.npz,
    report.json, report.md, particles.png, errors.png (with ground truth) and optionally particles.gif."""
    _setup_logging(False)
    _budget(memory_budget)
    import numpy as np

    from semmap.localization.filter import FilterSettings
    from semmap.localization.motion import MotionMode
    from semmap.localization.observation import ObservationKind
    from semmap.localization.run import InitMode
    from semmap.localization.sequence import LocalizeOptions, localize_sequence
    from semmap.types import pose_from_tum

    def choice(enum, value: str, what: str):
        try:
            return enum(value)
        except ValueError:
            raise SemmapError(f"unknown {what} {value!r}; choose from {', '.join(e.value for e in enum)}") from None

    start = None
    if init_pose is not None:
        try:
            with np.errstate(invalid="ignore", divide="ignore"):  # a zero quaternion is refused below, in one line
                start = pose_from_tum([float(v) for v in init_pose.replace(",", " ").split()])
        except (ValueError, IndexError):
            raise SemmapError(f"--init-pose must be 7 numbers 'tx ty tz qx qy qz qw', got {init_pose!r}") from None
    settings = FilterSettings(particles=particles, mode=choice(MotionMode, mode, "mode"),
                              model=choice(ObservationKind, model, "model"))
    options = LocalizeOptions(settings=settings, init=choice(InitMode, init, "initialisation"), init_pose=start,
                              motion=motion, motion_noise=motion_noise, segmenter=segmenter, weights=weights,
                              trust_weights=trust_weights, height=height, pitch_deg=pitch_deg, roll_deg=roll_deg,
                              points=points, stride=stride, max_frames=max_frames, seed=seed, gif=gif)
    with _interruptible():
        result, files = localize_sequence(map_path, sequence, out, options, progress=progress_bar("localizing"))
    summary = result.summary()
    _summary_out({**summary, "files": sorted(files)}, as_json, f"semmap localize: {out}",
                 _localize_rows(summary, out, sorted(files)))


def _localize_rows(s: dict, out: Path, files: list[str]) -> list[tuple[str, str]]:
    """``semmap localize``'s table: the filter, whether and when it converged, the final error, the cost."""
    converged = ("no" if s["frames_to_converge"] is None else
                 f"after {s['frames_to_converge']} updates ({s['seconds_to_converge']} s)")
    rows = [("filter", f"{s['particles']:,} particles, {s['model']} model, {s['mode']}, init {s['init']}, "
                       f"motion {s['motion']}"),
            ("updates", f"{s['updates']} ({s['frames_skipped']} frames skipped)"), ("converged", converged),
            ("converged at the end", "yes" if s["converged_at_end"] else "no")]
    if "pos_err_m_final" in s:
        rows.append(("final error", f"{_cm(s['pos_err_m_final'])}, {s['rot_err_deg_final']:.2f}°"))
        if "pos_err_m_after_convergence" in s:
            rows.append(("error after convergence", f"{_cm(s['pos_err_m_after_convergence']['median'])}, "
                                                    f"{s['rot_err_deg_after_convergence']['median']:.2f}° (median)"))
        rows.append(("on the true pose", "yes" if s["converged_to_truth"] else "no"))
    if s["ms_per_update"]:
        rows.append(("ms per update", f"{s['ms_per_update']['median']:.1f} (median)"))
    rows.append(("outputs", f"{out}: {', '.join(Path(f).name for f in files)}"))
    return rows


@app.command("eval-traj")
def eval_traj(
    gt: Annotated[Path, typer.Argument(help="reference: a TUM trajectory file, or a dataset folder with poses")],
    est: Annotated[list[Path], typer.Argument(help="estimated trajectories (TUM format); several are compared")],
    max_time_diff: Annotated[float, typer.Option(help="largest timestamp difference of matched poses (s)")] = 0.02,
    plot: Annotated[Path | None, typer.Option(help="write a trajectory plot PNG here")] = None,
    pairwise: Annotated[bool, typer.Option("--pairwise", help="also the ATE between every two estimates and the "
                                           "error they share")] = False,
    reference2: Annotated[Path | None, typer.Option(help="a second, independent reference (TUM file or dataset "
                                                    "folder): every trajectory is scored against it too")] = None,
    rotation_frames: Annotated[int | None, typer.Option(help="also compare relative rotations over N frames "
                                                        "between every two trajectories (no alignment needed)")
                               ] = None,
    plot_errors: Annotated[Path | None, typer.Option(help="write each estimate's position error per axis over the "
                                                     "frames to this PNG")] = None,
    as_json: _Json = False,
) -> None:
    """ATE (after SE(3) Umeyama alignment) and RPE of estimated trajectories against a reference; with several
    estimates, `--pairwise` or `--reference2`, a comparison of all of them."""
    _setup_logging(False)
    from semmap.runner import evaluate_trajectories

    scores = evaluate_trajectories(gt, est, max_time_diff=max_time_diff, pairwise=pairwise, reference2=reference2,
                                   rotation_frames=rotation_frames, plot=plot, plot_errors=plot_errors)
    rows = _traj_rows(scores) + [(what, str(path)) for what, path in (("plot", plot), ("error plot", plot_errors))
                                 if path is not None]
    _summary_out(scores, as_json, f"semmap eval-traj: against {gt}", rows)


def _scale(value: float | None) -> str:
    """A Sim(3) scale, or why there is none (a static camera cannot be aligned)."""
    return "- (alignment not possible)" if value is None else f"{value:.4f}"


def _traj_rows(scores: dict) -> list[tuple[str, str]]:
    """``semmap eval-traj``'s table: ATE, RPE and scale per estimate, then the comparisons asked for."""
    def scored(s: dict) -> str:
        return (f"ATE {_cm(s['ate_rmse_m'])}, RPE {_cm(s['rpe_trans_m'])} / {s['rpe_rot_deg']:.2f}° per frame, "
                f"Sim(3) scale {_scale(s['sim3_scale'])}, {s['matched']} poses matched")

    if "estimates" not in scores:
        s = scores
        return [("ATE (SE(3) aligned)", _cm(s["ate_rmse_m"])),
                ("ATE mean / median / max", " / ".join(_cm(s[k]) for k in ("ate_mean_m", "ate_median_m",
                                                                          "ate_max_m"))),
                ("RPE per frame", f"{_cm(s['rpe_trans_m'])}, {s['rpe_rot_deg']:.2f}°"),
                ("Sim(3) scale", _scale(s["sim3_scale"])),
                ("poses matched", f"{s['matched']} (reference {s['gt_poses']}, estimate {s['est_poses']})"),
                ("ground-truth path", f"{s['gt_path_length_m']:.2f} m")]
    rows = [(name, scored(s)) for name, s in scores["estimates"].items()]
    rows += [(f"{a} vs {b}", f"{_cm(p['ate_m'])} apart, {_cm(p['shared_m'])} of error shared")
             for p in scores.get("pairwise", []) for a, b in [p["between"]]]
    rows += [(f"{name} vs --reference2", f"ATE {_cm(s['ate_rmse_m'])}, {s['matched']} poses matched")
             for name, s in scores.get("reference2", {}).items()]
    if "rotation_disagreement_deg" in scores:
        r = scores["rotation_disagreement_deg"]
        rows.append((f"rotation over {r['frames']} frames", f"{r['common_frames']} common frames; the matrix of "
                                                          f"{', '.join(r['order'])} with --json"))
    return rows


@app.command("eval-seg")
def eval_seg(
    pred_dir: Annotated[Path, typer.Argument(help="folder of predicted label PNGs (class ids)")],
    gt_dir: Annotated[Path, typer.Argument(help="folder of ground-truth label PNGs with the same names")],
    num_classes: Annotated[int | None, typer.Option(help="number of classes K (ids 0..K-1); default: the label "
                                                        "set's, else the largest id in the images + 1")] = None,
    labelset: Annotated[Path | None, typer.Option(help="labelset.json naming the classes (default: the one in or "
                                                       "beside GT_DIR, as semmap simulate writes it)")] = None,
    ignore: Annotated[int, typer.Option(help="ground-truth id left out (255: VOC boundaries; -1: none)")] = 255,
    out: Annotated[Path | None, typer.Option(help="also write the scores as JSON here")] = None,
    resize: Annotated[bool, typer.Option("--resize", help="resize predictions of another size than their ground "
                                         "truth (nearest neighbour) instead of refusing them")] = False,
    as_json: _Json = False,
) -> None:
    """Segmentation accuracy of predicted label images: MIoU and MPA (eqs. 11-12), per-class IoU and accuracy,
    confusion matrix."""
    _setup_logging(False)
    from semmap.eval.segmentation import evaluate_label_folders

    result = evaluate_label_folders(pred_dir, gt_dir, num_classes, ignore=None if ignore < 0 else ignore,
                                    resize=resize, out=out, label_set=labelset)
    d = result.to_dict()
    classes = (f"{result.num_classes} from {result.label_set_path}" if result.label_set_path is not None
               else f"{result.num_classes} (ids 0..{result.num_classes - 1}, no labelset.json)")
    rows = [("images", f"{d['images']} scored, {len(d['missing_predictions'])} without a prediction"),
            ("classes", classes), *((name, "-" if d[k] is None else f"{d[k]:.4f}") for k, name in
                                    (("miou", "mIoU"), ("mpa", "MPA"), ("pixel_accuracy", "pixel accuracy")))]
    rows += [(f"IoU {name}", f"{'-' if c['iou'] is None else format(c['iou'], '.4f')} (accuracy "
                             f"{'-' if c['accuracy'] is None else format(c['accuracy'], '.4f')}, {c['pixels']:,} px)")
             for name, c in d["per_class"].items()]
    if out is not None:
        rows.append(("scores written to", str(out)))
    _summary_out(d, as_json, f"semmap eval-seg: {pred_dir} against {gt_dir}", rows)


@app.command("eval-map")
def eval_map(
    map_path: Annotated[Path, typer.Argument(metavar="MAP", help="a .semmap map file (any map), or a run folder "
                                             "holding map.semmap")],
    seq: Annotated[Path | None, typer.Argument(help="the labelled sequence it was built from (poses and label "
                                                    "images); may be left out with --gt-ply")] = None,
    format: Annotated[str, typer.Option(help=_FORMATS)] = AUTO,
    segmenter: Annotated[str | None, typer.Option(help="score this network's labels at the same pixels beside the "
                                                  "map's (precomputed --weights FOLDER: stored predictions); "
                                                  f"none: the map alone. {SEGMENTERS.choices()}")] = None,
    weights: Annotated[Path | None, typer.Option(help="segmenter weights, or the folder of predictions")] = None,
    every: Annotated[int, typer.Option(help="score every N-th frame")] = 10,
    pixel_stride: Annotated[int, typer.Option(help="score every k-th pixel row and column")] = 1,
    max_frames: Annotated[int | None, typer.Option(help="read at most N frames")] = None,
    gt_ply: Annotated[Path | None, typer.Option(help="labelled ground-truth points or mesh vertices (PLY, e.g. "
                                                "ScanNet's *_vh_clean_2.labels.ply): mIoU, f.w. mIoU and mean class "
                                                "accuracy over them, in the map's class ids")] = None,
    gt_label_property: Annotated[str, typer.Option(help="the vertex property of --gt-ply holding the class")
                                 ] = "label",
    out: Annotated[Path | None, typer.Option(help="also write the scores as JSON here")] = None,
) -> None:
    """A map scored at the pixels of a labelled sequence: the map's label at each pixel's 3D point against the true
    label, beside the network's own label at the same pixels (MIoU, accuracy, MPA, coverage, the fusion ceiling);
    with --gt-ply, at a dataset's labelled points or mesh vertices as the benchmarks score maps."""
    _setup_logging(False)
    from semmap.errors import ConfigError
    from semmap.run.eval_map import evaluate_map_file, evaluate_map_points

    if seq is None and gt_ply is None:
        raise ConfigError("eval-map needs the labelled sequence SEQ, or --gt-ply, or both")
    pixels = functools.partial(evaluate_map_file, map_path, seq, format=format, segmenter=segmenter, weights=weights,
                               every=every, stride=pixel_stride, max_frames=max_frames)
    points = functools.partial(evaluate_map_points, map_path, gt_ply, label_property=gt_label_property)
    if gt_ply is None:
        scores = pixels(out=out)
    elif seq is None:
        scores = points(out=out)
    else:  # both: one JSON of both, its --out checked against every input first
        from semmap.files.atomic import write_text_atomic
        from semmap.files.outputs import OutputKind, check_outputs

        check_outputs([("--out", out, OutputKind.FILE)], [("MAP", map_path), ("SEQ", seq), ("--gt-ply", gt_ply)])
        scores = {**points(out=None), **pixels(out=None)}
        if out is not None:
            write_text_atomic(out, json.dumps(scores, indent=2))
    typer.echo(json.dumps(scores, indent=2))


@app.command()
def info(path: Annotated[Path, typer.Argument(help="a map file: .ot, .bt, .semmap (any map) or .ply")]) -> None:
    """Describe a map file: kind, resolution, voxels or points, occupied and free, classes, fusion rule."""
    _setup_logging(False)
    from semmap.io.map_info import describe_map_file

    typer.echo(json.dumps(describe_map_file(path), indent=2))


@app.command()
def batch(
    datasets: Annotated[list[Path], typer.Argument(help="sequences: folders, ROS 1 .bag files or ROS 2 bag folders")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder: one sub-folder per sequence, batch.json "
                                      "and batch.md")],
    address: Annotated[str | None, typer.Option(help="an existing Ray cluster (ray://HEAD:10001, HEAD:6379 or auto); "
                                                "default: start a local one")] = None,
    workers: Annotated[int | None, typer.Option(help="CPUs of the local cluster (default: all)")] = None,
    cpus_per_run: Annotated[float, typer.Option(help="CPUs one sequence asks of a Ray node")] = 2,
    resume: Annotated[bool, typer.Option("--resume/--no-resume", help="skip sequences whose outputs of the same "
                                         "configuration are complete")] = True,
    config: Annotated[Path | None, typer.Option(help="a run's config.json to use for every sequence (its dataset "
                                                "and output folder are replaced); the options below are then "
                                                "ignored")] = None,
    format: Annotated[str, typer.Option(help=_FORMATS)] = AUTO,
    max_frames: Annotated[int | None, typer.Option(help="use at most N frames")] = None,
    stride: Annotated[int, typer.Option(help="use every k-th frame")] = _default(InputConfig, "stride"),
    resolution: Annotated[float, typer.Option(help="finest voxel size (m)")] = _default(MappingConfig, "resolution"),
    semantics: Annotated[str, typer.Option(help=_SOURCES)] = _default(SemanticsConfig, "source").value,
    segmenter: Annotated[str | None, typer.Option(help=SEGMENTERS.choices())] = None,
    weights: Annotated[Path | None, typer.Option(help="segmenter weights")] = None,
    poses: Annotated[str, typer.Option(help=f"{GROUND_TRUTH} | a tracker | PATH (see semmap run)")] = GROUND_TRUTH,
    strict: Annotated[bool, typer.Option("--strict", help="stop a sequence at its first unusable frame")] = False,
) -> None:
    """Map many sequences as Ray tasks (one `semmap run` each), locally or on a cluster; resumes a half-finished
    batch and writes a summary table."""
    _setup_logging(False)
    from semmap.batch import plan, run_batch, write_summary
    from semmap.config import InputConfig, MappingConfig, OutputConfig, PosesConfig, RunConfig, SemanticsConfig

    if config is not None:
        from semmap.files.safe import read_text_limited

        text = read_text_limited(config, what="run configuration")
        template = _validated(lambda: RunConfig.model_validate_json(text), source=config)
    else:
        template = _validated(lambda: RunConfig(
            input=InputConfig(dataset=datasets[0], format=format, stride=stride, max_frames=max_frames,
                              strict=strict),
            mapping=MappingConfig(resolution=resolution),
            semantics=SemanticsConfig(source=semantics, segmenter=segmenter, weights=weights),
            poses=PosesConfig(source=poses), output=OutputConfig(out=out)))
    items = plan(datasets, out)
    console = _console()

    def show(row) -> None:
        detail = f"{row.seconds:.1f} s on {row.node}" if row.seconds is not None else ""
        console.print(f"{row.sequence}: {row.status}" + (f" ({detail})" if detail else "")
                      + (f": {row.error}" if row.error else ""))

    result = run_batch(template, items, address=address, workers=workers, cpus_per_run=cpus_per_run, resume=resume,
                       on_row=show)
    _, md_path = write_summary(out, result)
    summary = result.to_dict()
    console.print(f"{summary['sequences']} sequences: {summary['done']} mapped, {summary['already_done']} already "
                  f"done, {summary['failed']} failed in {summary['seconds']:.1f} s; {md_path}")
    if summary["failed"]:
        raise SemmapError(f"{summary['failed']} of {summary['sequences']} sequences failed; see {md_path}")


@app.command()
def view(
    path: Annotated[Path, typer.Argument(help="a map file: .semmap (any map), .ply, .ot or .bt")],
    save: Annotated[Path | None, typer.Option(help="write a rerun recording (.rrd) instead of opening a viewer")
                    ] = None,
) -> None:
    """Open a finished map in the rerun viewer (voxels in class colours, class names on hover)."""
    _setup_logging(False)
    from semmap.viz.rerun_log import view_map

    n = view_map(path, save=save, spawn=save is None)
    what = "PLY vertices" if path.suffix == ".ply" else "occupied voxels"
    _console().print(f"{path}: {n:,} {what}" + (f" written to {save}" if save else " sent to rerun"))


@app.command()
def diff(
    before: Annotated[Path, typer.Argument(help="the earlier map: .semmap or a run folder")],
    after: Annotated[Path, typer.Argument(help="the later map of the same place, in the same frame")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder: diff.json, diff.ply, diff.png")],
    match_radius: Annotated[float, typer.Option(help="objects of one class closer than this are the same object "
                                                "(m); farther ones pair as moved by space, size and colour")] = 1.0,
    move_threshold: Annotated[float, typer.Option(help="a matched object farther than this moved (m)")] = 0.2,
) -> None:
    """What changed between two maps of one place: voxels that appeared, disappeared or changed class (only where
    both maps saw the space) and, for run folders with objects.json, objects that appeared, disappeared or moved."""
    _setup_logging(False)
    from semmap.products.export import export_diff

    s = export_diff(before, after, out, match_radius=match_radius, move_threshold=move_threshold)
    v, o = s["voxels"], s["objects"]
    objects = "" if o is None else (f"; objects: {o['appeared']} appeared, {o['disappeared']} disappeared, "
                                    f"{o['moved']} moved, {o.get('unknown', 0)} unknown")
    typer.echo(f"{out}: voxels {v['appeared']:,} appeared, {v['disappeared']:,} disappeared, {v['relabelled']:,} "
               f"changed class ({v['observed_by_both']:,} seen by both){objects}")


@app.command()
def merge(
    map_a: Annotated[Path, typer.Argument(metavar="A", help="a map: .semmap (OctoMap, voxel grid or point map) or a "
                                          "run folder; the merged map is in its frame")],
    map_b: Annotated[Path, typer.Argument(metavar="B", help="a map of the same place, kind, resolution and classes")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output: a folder (the map's files, transform.txt, "
                                      "merge.json) or a .semmap file; never A or B")],
    transform: Annotated[Path | None, typer.Option(help="text file of the 4x4 transform taking B's coordinates into "
                                                   "A's frame (default: estimated from the occupied voxels)")] = None,
    min_overlap: Annotated[float, typer.Option(help="refuse an estimated alignment unless this share of the smaller "
                                               "map's occupied voxels meets the other map")] = 0.3,
    as_json: _Json = False,
) -> None:
    """Merge two maps of one place: B aligned to A (a given transform, or FPFH + RANSAC then ICP, checked for a
    sane overlap), evidence combined by the maps' own occupancy update and fusion rule."""
    _setup_logging(False)
    from semmap.products.merge import merge_map_files

    s = merge_map_files(map_a, map_b, out, transform=transform, min_overlap=min_overlap)
    al, occ = s["alignment"], s["occupied"]
    rows = [("alignment", f"{al['source']}" + (f" (from the {al['start']})" if al["start"] else "")),
            ("overlap", f"{100 * al['overlap']:.1f} % of the smaller map's occupied voxels, RMSE "
                        f"{100 * al['rmse_m']:.2f} cm"),
            ("occupied voxels", f"A {occ['a']:,}, B {occ['b']:,}, merged {occ['merged']:,}"),
            ("written", str(out))]
    _summary_out(s, as_json, f"semmap merge: {s['kind']} at {s['resolution']} m", rows)


export_app = typer.Typer(no_args_is_help=True, help="Robot products from a finished map: a 2D navigation grid "
                         "and semantic costmap (ROS map_server), a Euclidean signed distance field, the semantic "
                         "mesh of a TSDF.")
app.add_typer(export_app, name="export")

_ExportMap = Annotated[Path, typer.Argument(help="a map: .semmap (any kind) or a run folder")]
_ExportOut = Annotated[Path, typer.Option("--out", "-o", help="output folder (written whole or not at all)")]
_Region = Annotated[str | None, typer.Option(help="bounded region 'xmin ymin zmin xmax ymax zmax' (m; default: "
                                                  "everything the map knows)")]


def _region(text: str | None) -> tuple[float, ...] | None:
    from semmap.limits import check_option

    return check_option("--region", text)


def _class_costs(items: list[str]) -> dict[str, int]:
    from semmap.errors import ConfigError

    out = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            out[name.strip()] = int(value)
        except ValueError:
            raise ConfigError(f"--cost {item!r}: write CLASS=COST with COST a whole number 0..100") from None
    return out


@export_app.command("grid")
def export_grid_command(
    map_path: _ExportMap,
    out: _ExportOut,
    z_min: Annotated[float, typer.Option(help="band above the floor that blocks the robot: from (m)")] = 0.1,
    z_max: Annotated[float, typer.Option(help="... to (m): the robot's height")] = 1.5,
    floor: Annotated[float | None, typer.Option(help="floor height (m; default: detected from floor-class voxels, "
                                                     "else the lowest dense layer)")] = None,
    no_go: Annotated[str, typer.Option(help="classes never to enter, comma-separated (e.g. person,stairs)")] = "",
    cost: Annotated[list[str] | None, typer.Option(help="CLASS=COST (0..100) for the costmap, repeatable (e.g. "
                                                        "door=50)")] = None,
    inflation: Annotated[float, typer.Option(help="robot radius (m): costmap cells this close to an obstacle "
                                                  "get cost 99")] = 0.0,
    region: _Region = None,
) -> None:
    """A 2D occupancy grid (map.pgm + map.yaml, ROS map_server trinary) and a semantic costmap (costmap.png +
    costmap.yaml in scale mode, costmap.npy exact) from a map; unknown space stays unknown."""
    _setup_logging(False)
    from semmap.products.export import export_grid
    from semmap.products.navgrid import GridOptions

    options = GridOptions(z_min=z_min, z_max=z_max, floor=floor,
                          no_go=tuple(n.strip() for n in no_go.split(",") if n.strip()),
                          costs=_class_costs(cost or []), inflation=inflation)
    s = export_grid(map_path, out, options, _region(region))
    c = s["cells"]
    typer.echo(f"{out}: {s['size_cells'][0]}x{s['size_cells'][1]} cells at {s['resolution']} m, floor "
               f"{s['floor_z']:.2f} m; occupied {c['occupied']:,}, free {c['free']:,}, unknown {c['unknown']:,}")


@export_app.command("scene-graph")
def export_scene_graph_command(
    run: Annotated[Path, typer.Argument(help="a run folder with objects.json (semmap run ... --instances ...)")],
    out: _ExportOut,
    sequence: Annotated[Path | None, typer.Option(help="the run's sequence (default: the one its config.json "
                                                       "names); a simulated one gives the true rooms")] = None,
    near: Annotated[float, typer.Option(help="objects of one room closer than this are 'near' (m)")] = 1.0,
    door_width: Annotated[float, typer.Option(help="room segmentation of real maps: doors narrower than this "
                                                   "separate rooms (m)")] = 1.0,
) -> None:
    """A scene graph (scene_graph.json, spark-dsg / Hydra): objects, rooms (the simulator's layout, or a room
    segmentation of the map's navigation grid) and relations (in room, on, near)."""
    _setup_logging(False)
    from semmap.products.export import export_scene_graph

    s = export_scene_graph(run, out, sequence=sequence, near=near, door_width=door_width)
    c = s["counts"]
    typer.echo(f"{out}: {c['objects']} objects, {c['rooms']} rooms (from the {s['rooms_from']}); relations: "
               f"{c['in']} in, {c['on']} on, {c['near']} near")


@export_app.command("esdf")
def export_esdf_command(
    map_path: _ExportMap,
    out: _ExportOut,
    region: _Region = None,
    slice_z: Annotated[float | None, typer.Option(help="height of the slice picture (m; default: the middle)")] = None,
) -> None:
    """A Euclidean signed distance field at the map's resolution (esdf.npz: distance, observed, origin, resolution;
    positive outside obstacles, negative inside) and a slice picture."""
    _setup_logging(False)
    from semmap.products.export import export_esdf

    s = export_esdf(map_path, out, _region(region), slice_z)
    n = s["size_voxels"]
    typer.echo(f"{out}: {n[0]}x{n[1]}x{n[2]} voxels at {s['resolution']} m in {s['ms']:.0f} ms; largest distance "
               f"{s['max_distance_m']} m")
@export_app.command("mesh")
def export_mesh_command(
    map_path: Annotated[Path, typer.Argument(help="a run folder of 'semmap run --maps ...,tsdf', or its tsdf.semmap")],
    out: _ExportOut,
    min_weight: Annotated[int, typer.Option(help="observations a TSDF voxel needs to count")] = 1,
) -> None:
    """The semantic mesh (mesh.ply: per-vertex colour, class, confidence and class probabilities) by marching cubes
    over the TSDF, classes from the run folder's semantic map (its OctoMap first), else the TSDF's own."""
    _setup_logging(False)
    from semmap.products.export import export_mesh

    s = export_mesh(map_path, out, min_weight=min_weight)
    typer.echo(f"{out}: {s['vertices']:,} vertices, {s['faces']:,} triangles in {s['ms']:.0f} ms; classes from "
               f"{s['labels_from']}, {100 * s['classified_share']:.1f}% of vertices classified")


def _numbers_checked(command: str, callback):
    """``callback`` of ``command`` with every numeric option checked against ``semmap.limits`` first, so a bad
    number is refused in one line naming the option before any work (the library checks them again)."""

    @functools.wraps(callback)
    def checked(**kwargs):
        from semmap import limits

        names = _long_options(command)
        limits.check_options(command, {names.get(name, name): value for name, value in kwargs.items()})
        return callback(**kwargs)

    return checked


@functools.cache
def _long_options(command: str) -> dict[str, str]:
    """Parameter name -> ``--option`` of one command (``export grid``: a command of a sub-app)."""
    group = typer.main.get_command(app)
    for word in command.split():
        group = group.commands[word]
    return {p.name: next((o for o in p.opts if o.startswith("--")), p.name) for p in group.params}


def _command_name(info) -> str:
    return info.name or info.callback.__name__.replace("_", "-")


for _info in app.registered_commands:  # every command, present and future
    _info.callback = _numbers_checked(_command_name(_info), _info.callback)
for _group in app.registered_groups:  # and every command of a sub-app (semmap export ...)
    for _info in _group.typer_instance.registered_commands:
        _info.callback = _numbers_checked(f"{_group.name} {_command_name(_info)}", _info.callback)


def main() -> None:
    """Entry point: known errors become one line on stderr and exit code 1."""
    try:
        app()
    except SemmapError as exc:
        print(f"semmap: error: {exc}", file=sys.stderr)
        sys.exit(1)
    except OSError as exc:  # a full disk, a read-only file system, a refused name: one line, not a traceback
        from semmap.files.outputs import write_failure

        if (error := write_failure(exc)) is None:
            raise
        print(f"semmap: error: {error}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt as exc:
        from semmap.interrupt import RunInterrupted

        print(f"semmap: {exc}" if isinstance(exc, RunInterrupted) else "semmap: interrupted", file=sys.stderr)
        sys.exit(130)
    except SystemError as exc:  # a second Ctrl-C inside a numba kernel surfaces as SystemError
        if not isinstance(exc.__cause__ or exc.__context__, KeyboardInterrupt):
            raise
        print("semmap: interrupted", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    main()
