"""The map family: ``semmap run`` (map a sequence), ``demo``, ``batch`` (many sequences on Ray), ``view`` and
``info`` (a finished map file)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from semmap.cli.options import (
    FORMATS_HELP,
    SOURCES_HELP,
    MemoryBudget,
    budget,
    default,
    parse_color_mode,
    parse_size,
    validated,
)
from semmap.cli.terminal import interruptible, print_summary, progress_bar, setup_logging, stderr_console
from semmap.config import CrfConfig, InputConfig, MappingConfig, ObjectsConfig, OutputConfig, SemanticsConfig
from semmap.datasets import AUTO
from semmap.errors import SemmapError
from semmap.fusion.crf import CRF_KEYS, parse_crf_params
from semmap.fusion.rules import FusionRule
from semmap.maps.registry import MAPS, own_rules
from semmap.perception.instances.registry import INSTANCE_SOURCES
from semmap.perception.registry import SEGMENTERS, SegmenterName
from semmap.poses.track import GROUND_TRUTH, pose_sources_help

_INPUT = "Input"
_MAPPING = "Mapping"
_SEMANTICS = "Semantics"
_OUTPUT = "Output"
_POSES = "Poses"
_OBJECTS = "Objects"
_ROS = "ROS bags"
_MAPS = "Maps and fusion"
#: ``--fusion`` help and the default ``--maps``, from the registries and the configuration.
_RULES = " | ".join(r.value for r in FusionRule)
_DEFAULT_MAPS = ",".join(kind.value for kind in default(MappingConfig, "maps"))



def run(
    dataset: Annotated[Path, typer.Argument(help="RGB-D sequence: TUM RGB-D or 7-Scenes folder, ROS 1 .bag or ROS 2 "
                                                 "bag folder")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder", rich_help_panel=_OUTPUT)],
    format: Annotated[str, typer.Option(help=FORMATS_HELP, rich_help_panel=_INPUT)] = AUTO,
    labels: Annotated[Path | None, typer.Option(help="folder of label PNGs (class ids) matched to frames by name",
                                                 rich_help_panel=_INPUT)] = None,
    max_frames: Annotated[int | None, typer.Option(help="use at most N frames", rich_help_panel=_INPUT)] = None,
    stride: Annotated[int, typer.Option(help="use every k-th frame",
                                        rich_help_panel=_INPUT)] = default(InputConfig, "stride"),
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
                                              rich_help_panel=_MAPPING)] = default(MappingConfig, "resolution"),
    min_depth: Annotated[float, typer.Option(help="ignore depth below (m)",
                                             rich_help_panel=_MAPPING)] = default(MappingConfig, "min_depth"),
    max_depth: Annotated[float, typer.Option(help="ignore depth above (m)",
                                             rich_help_panel=_MAPPING)] = default(MappingConfig, "max_depth"),
    max_range: Annotated[float, typer.Option(help="OctoMap max range (m), -1 = none",
                                             rich_help_panel=_MAPPING)] = default(MappingConfig, "max_range"),
    pixel_stride: Annotated[int, typer.Option(help="use every k-th pixel row/column",
                                              rich_help_panel=_MAPPING)] = default(MappingConfig, "pixel_stride"),
    semantics: Annotated[str, typer.Option(help=SOURCES_HELP,
                                           rich_help_panel=_SEMANTICS)] = default(SemanticsConfig, "source").value,
    label_confidence: Annotated[float, typer.Option(help="confidence of hard labels", rich_help_panel=_SEMANTICS)
                                ] = default(SemanticsConfig, "label_confidence"),
    temperature: Annotated[float, typer.Option(help="fuse softmax(logits / T) of the segmenter's classes: > 1 softens "
                                                    "over-confident probabilities, < 1 sharpens, 1 = as given",
                                               rich_help_panel=_SEMANTICS)] = default(SemanticsConfig,
                                                                                       "temperature"),
    lam: Annotated[float, typer.Option("--lambda", help="penalty λ of the top-k fusion (Algorithm 1)",
                                       rich_help_panel=_SEMANTICS)] = default(SemanticsConfig, "lam"),
    segmenter: Annotated[str | None, typer.Option(help=f"{SEGMENTERS.choices()} (onnx:MODEL.onnx, hf:MODEL_ID; "
                                                       "NAME+structure adds wall, floor and ceiling from depth; "
                                                       "default: from --semantics, and espnetv2+structure for a "
                                                       "real recording without label images)",
                                                  rich_help_panel=_SEMANTICS)] = None,
    up: Annotated[str | None, typer.Option(help="the world frame's up axis (+z, -y, ... or x,y,z) when it is "
                                                "gravity-aligned: the structure segmenter's up (default: the "
                                                "recording's accelerometer, else estimated from depth)",
                                           rich_help_panel=_SEMANTICS)] = None,
    weights: Annotated[Path | None, typer.Option(help="network weights (default: the shipped weights/ of espnetv2 "
                                                 "and semmap's networks), or the predictions folder (precomputed)",
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
                                               rich_help_panel=_SEMANTICS)] = default(SemanticsConfig,
                                                                                       "segment_every"),
    keyframes: Annotated[bool, typer.Option("--keyframes", help="segment only frames where the camera moved "
                                            "10 cm or turned 10° since the last segmented one",
                                            rich_help_panel=_SEMANTICS)] = False,
    batch_size: Annotated[int, typer.Option(help="frames per network batch",
                                            rich_help_panel=_SEMANTICS)] = default(SemanticsConfig, "batch_size"),
    backend: Annotated[str, typer.Option(help="torch | onnx: network runtime",
                                         rich_help_panel=_SEMANTICS)] = default(SemanticsConfig, "backend"),
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
                                            rich_help_panel=_OUTPUT)] = default(OutputConfig, "color_mode").value,
    rerun: Annotated[Path | None, typer.Option(help="log images, poses and the growing map to this rerun "
                                               "recording (.rrd)", rich_help_panel=_OUTPUT)] = None,
    rerun_spawn: Annotated[bool, typer.Option("--rerun-spawn", help="watch the map grow in a rerun viewer",
                                              rich_help_panel=_OUTPUT)] = False,
    rerun_map_every: Annotated[int, typer.Option(help="frames between two logs of the whole map to rerun",
                                                 rich_help_panel=_OUTPUT)] = default(OutputConfig, "rerun_map_every"),
    cloud: Annotated[bool, typer.Option("--cloud/--no-cloud", help="also write cloud.ply, the dense coloured cloud of "
                                        "every frame's points (one per --point-resolution cell) the report's storage "
                                        "table compares the maps with (a grid insertion per frame, a large file)",
                                        rich_help_panel=_OUTPUT)] = default(OutputConfig, "cloud"),
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
                                ] = default(MappingConfig, "point_resolution"),
    tsdf_voxel: Annotated[float | None, typer.Option(help="voxel of the TSDF (m; default: --resolution)",
                                                     rich_help_panel=_MAPS)] = None,
    tsdf_truncation: Annotated[float, typer.Option(help="TSDF truncation distance in voxels",
                                                   rich_help_panel=_MAPS)] = default(MappingConfig,
                                                                                      "tsdf_truncation"),
    decay: Annotated[float, typer.Option(help="share of log-odds an OctoMap cell not observed in a frame loses "
                                              "towards unknown (0: none)", rich_help_panel=_MAPS)
                     ] = default(MappingConfig, "decay"),
    dynamic: Annotated[str, typer.Option(help="dynamic classes, comma-separated (the whole list, e.g. person,chair; "
                                              "none for no class): their points clear free space along their "
                                              "rays but never occupy a voxel", rich_help_panel=_MAPS)
                       ] = ",".join(default(MappingConfig, "dynamic")),
    top_k: Annotated[int, typer.Option(help="classes per top-k set (1..8): the segmenter's sets and topk fusion",
                                       rich_help_panel=_MAPS)] = default(SemanticsConfig, "k"),
    max_confidence: Annotated[float, typer.Option(help="cap on a voxel's top confidence (topk, max)",
                                                  rich_help_panel=_MAPS)] = default(SemanticsConfig,
                                                                                     "max_confidence"),
    class_prior: Annotated[Path | None, typer.Option(help="bayes-prior: JSON {class name: frequency} "
                                                     "(default uniform)", rich_help_panel=_MAPS)] = None,
    crf: Annotated[bool, typer.Option("--crf", help="refine every map with a 3D dense CRF after mapping",
                                      rich_help_panel=_MAPS)] = False,
    crf_every: Annotated[int, typer.Option(help="with --crf, also refine every N keyframes while mapping",
                                           rich_help_panel=_MAPS)] = default(CrfConfig, "every"),
    crf_params: Annotated[str | None, typer.Option(help="with --crf, its kernels as key=value,... (keys: "
                                                        f"{', '.join(CRF_KEYS)}; 'semanticfusion' for "
                                                        "SemanticFusion's values; docs/EXPERIMENTS.md)",
                                                   rich_help_panel=_MAPS)] = None,
    instances: Annotated[str | None, typer.Option(help=f"{INSTANCE_SOURCES.choices()}: also build the object map "
                                                   "(objects.json, objects.ply)", rich_help_panel=_OBJECTS)] = None,
    instance_weights: Annotated[Path | None, typer.Option(help="Mask R-CNN weights (--instances maskrcnn)",
                                                          rich_help_panel=_OBJECTS)] = None,
    instance_errors: Annotated[str, typer.Option(help="oracle instances' errors: exact | maskrcnn-like | noisy",
                                                 rich_help_panel=_OBJECTS)] = default(ObjectsConfig, "errors"),
    adapt: Annotated[bool, typer.Option("--adapt", help="map, let the map teach the network (semmap adapt), map "
                                        "again: rounds in OUT/round-N, weights in OUT/adapt-N/best.pt",
                                        rich_help_panel=_SEMANTICS)] = False,
    adapt_rounds: Annotated[int, typer.Option(help="with --adapt: rounds of adapting and mapping again",
                                              rich_help_panel=_SEMANTICS)] = 1,
    adapt_steps: Annotated[int, typer.Option(help="with --adapt: SGD steps of each adaptation",
                                             rich_help_panel=_SEMANTICS)] = 300,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="debug logging")] = False,
    memory_budget: MemoryBudget = None,
) -> None:
    """Map an RGB-D sequence: writes map.ot, map.bt, map.semmap (and voxelgrid.* / points.* for --maps,
    objects.json / objects.ply for --instances), cloud.ply (with --cloud: the dense coloured cloud), preview.png,
    trajectory.txt, report.json, report.md and config.json."""
    setup_logging(verbose)
    budget(memory_budget)
    from semmap.config import LoopMode, OnlineConfig, PosesConfig, RosConfig, RunConfig
    from semmap.maps.registry import map_kind
    from semmap.runner import run_config

    kinds = tuple(map_kind(name.strip()) for name in maps.split(",") if name.strip())
    if not crf and (crf_params is not None or crf_every != default(CrfConfig, "every")):
        raise SemmapError(f"{'--crf-params' if crf_params is not None else '--crf-every'} sets the dense CRF, which "
                          f"runs only with --crf")

    config = validated(lambda: RunConfig(
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
                                  max_confidence=max_confidence, segmenter=segmenter, up=up,
                                  weights=weights, trust_weights=trust_weights, segmenter_config=segmenter_config,
                                  class_map=class_map, calibration=calibration, segment_every=segment_every,
                                  keyframes=keyframes,
                                  batch_size=batch_size, backend=backend, input_size=parse_size(input_size),
                                  fusion=fusion, class_prior=class_prior),
        poses=PosesConfig(source=poses),
        mode=LoopMode.ONLINE if online else LoopMode.OFFLINE,
        online=OnlineConfig(rate=rate),
        crf=CrfConfig(enabled=crf, every=crf_every, **parse_crf_params(crf_params)),
        objects=ObjectsConfig(instances=instances, weights=instance_weights, errors=instance_errors),
        output=OutputConfig(out=out, color_mode=parse_color_mode(color_mode), rerun=rerun, rerun_spawn=rerun_spawn,
                            rerun_map_every=rerun_map_every, cloud=cloud),
    ))
    if adapt:
        if resume or continue_from is not None or checkpoint_every:
            raise SemmapError("--adapt continues a killed loop by itself (run the same command again); it takes no "
                              "--resume, --continue or --checkpoint-every")
        from semmap.cli.train import run_adapting

        return run_adapting(config, adapt_rounds, adapt_steps)
    with interruptible():
        result = run_config(config, progress=progress_bar("mapping"),
                            track_progress=progress_bar(f"tracking ({poses})"), checkpoint_every=checkpoint_every,
                            resume=resume, continue_from=continue_from)
    try:
        print_summary(result.report, result.out_dir)
    except KeyboardInterrupt:  # the outputs are complete by now: say so, and it is a success
        print(f"semmap: Ctrl-C after the run had finished; its outputs in {result.out_dir} are complete",
              file=sys.stderr)


def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")] = Path("outputs/demo"),
    frames: Annotated[int, typer.Option(help="frames of the default trajectory")] = 300,
    resolution: Annotated[float, typer.Option(help="finest voxel size (m)")] = default(MappingConfig, "resolution"),
    scene_seed: Annotated[int, typer.Option(help="scene generator seed")] = 0,
    rerun: Annotated[Path | None, typer.Option(help="also log the run to this rerun recording (.rrd)")] = None,
    semantics: Annotated[str, typer.Option(help="network (the shipped network named in weights/manifest.json, "
                                                "ONNX Runtime) | oracle (the cnn-like error model)")] = "network",
    trust_weights: Annotated[bool, typer.Option("--trust-weights", help="use shipped weights whose sha256 differs "
                                                "from weights/manifest.json (with a warning)")] = False,
    cloud: Annotated[bool, typer.Option("--cloud", help="also write cloud.ply, the dense coloured cloud the storage "
                                        "table compares the maps with")] = default(OutputConfig, "cloud"),
) -> None:
    """Simulate the default scene, map it with ground-truth poses and the shipped segmentation network (or the
    cnn-like oracle), and write the outputs of `semmap run` plus report.md with 3D accuracy against ground truth."""
    setup_logging(False)
    from semmap.runner import run_demo

    if semantics not in ("network", SegmenterName.ORACLE):
        raise SemmapError(f"--semantics must be network or oracle, got {semantics!r}")
    with interruptible():
        result = validated(lambda: run_demo(out=out, frames=frames, resolution=resolution, scene_seed=scene_seed,
                                             rerun=rerun, oracle=semantics == SegmenterName.ORACLE,
                                             trust_weights=trust_weights, cloud=cloud,
                                             progress=progress_bar("simulate + map")))
    print_summary(result.report, result.out_dir)


def info(path: Annotated[Path, typer.Argument(help="a map file (.ot, .bt, .semmap, .ply) or any file semmap writes "
                                                  "beside it (mesh, grid, costmap, ESDF, scene graph, diff, their "
                                                  "summaries, objects, trajectories, pictures)")]) -> None:
    """Describe a map file (kind, resolution, voxels or points, occupied and free, classes, fusion rule) or a
    product of export, diff and merge."""
    setup_logging(False)
    from semmap.io.map_info import describe_map_file

    typer.echo(json.dumps(describe_map_file(path), indent=2))


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
    format: Annotated[str, typer.Option(help=FORMATS_HELP)] = AUTO,
    max_frames: Annotated[int | None, typer.Option(help="use at most N frames")] = None,
    stride: Annotated[int, typer.Option(help="use every k-th frame")] = default(InputConfig, "stride"),
    resolution: Annotated[float, typer.Option(help="finest voxel size (m)")] = default(MappingConfig, "resolution"),
    semantics: Annotated[str, typer.Option(help=SOURCES_HELP)] = default(SemanticsConfig, "source").value,
    segmenter: Annotated[str | None, typer.Option(help=SEGMENTERS.choices())] = None,
    weights: Annotated[Path | None, typer.Option(help="segmenter weights")] = None,
    poses: Annotated[str, typer.Option(help=f"{GROUND_TRUTH} | a tracker | PATH (see semmap run)")] = GROUND_TRUTH,
    strict: Annotated[bool, typer.Option("--strict", help="stop a sequence at its first unusable frame")] = False,
) -> None:
    """Map many sequences as Ray tasks (one `semmap run` each), locally or on a cluster; resumes a half-finished
    batch and writes a summary table."""
    setup_logging(False)
    from semmap.batch import plan, run_batch, write_summary
    from semmap.config import InputConfig, MappingConfig, OutputConfig, PosesConfig, RunConfig, SemanticsConfig

    if config is not None:
        from semmap.files.safe import read_text_limited

        text = read_text_limited(config, what="run configuration")
        template = validated(lambda: RunConfig.model_validate_json(text), source=config)
    else:
        template = validated(lambda: RunConfig(
            input=InputConfig(dataset=datasets[0], format=format, stride=stride, max_frames=max_frames,
                              strict=strict),
            mapping=MappingConfig(resolution=resolution),
            semantics=SemanticsConfig(source=semantics, segmenter=segmenter, weights=weights),
            poses=PosesConfig(source=poses), output=OutputConfig(out=out)))
    items = plan(datasets, out)
    console = stderr_console()

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


def view(
    path: Annotated[Path, typer.Argument(help="a map file (.semmap, .ply, .ot, .bt) or a product semmap writes "
                                              "(mesh.ply, map.yaml, costmap.npy, esdf.npz, scene_graph.json, "
                                              "diff.json, objects.json, a trajectory, a picture)")],
    save: Annotated[Path | None, typer.Option(help="write a rerun recording (.rrd) instead of opening a viewer")
                    ] = None,
    html: Annotated[Path | None, typer.Option(help="write the map in 3D as one offline web page (classes to hide "
                                                   "and show, objects and camera path of its run folder) instead")
                    ] = None,
) -> None:
    """Open a finished map in the rerun viewer (voxels in class colours, class names on hover), or a product: the
    mesh, the grid as an image and floor cells, the ESDF as points by distance, the scene graph as boxes and
    edges; --html writes a map as a web page instead."""
    setup_logging(False)
    if html is not None and save is not None:
        raise SemmapError("--html and --save each write the view: give one of them")
    if html is not None:
        from semmap.viz.web_view import write_map_view

        shown = write_map_view(path, html)
        stderr_console().print(f"{path}: {shown.voxels:,} voxels, {shown.drawn:,} drawn in {html}"
                               + (f" ({shown.note})" if shown.note else ""))
        return
    from semmap.viz.rerun_log import view_map
    from semmap.viz.rerun_products import is_product_file, shown

    n = view_map(path, save=save, spawn=save is None)
    what = shown(path) if is_product_file(path) else "PLY vertices" if path.suffix == ".ply" else "occupied voxels"
    stderr_console().print(f"{path}: {n:,} {what}" + (f" written to {save}" if save else " sent to rerun"))
