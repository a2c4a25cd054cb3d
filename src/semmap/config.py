"""Run configuration: one pydantic model per section and one root model, written next to every result.

The run layer reads it (``runner.py``, ``pipeline.py``, the ``get_*`` / ``*_for`` factories in ``factories.py``);
components take plain arguments. Fields that name a family (segmenter, instance source, pose source, dataset
format, maps, fusion rule) are typed with the enum of that family's registry.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import ClassVar

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from semmap.datasets import AUTO, FORMATS, DatasetFormat
from semmap.errors import ConfigError
from semmap.fusion.crf import CRF_KEYS, CrfParams
from semmap.fusion.rules import FusionRule
from semmap.fusion.topk_bayes import DEFAULT_LAMBDA, DEFAULT_MAX_CONFIDENCE
from semmap.geometry import DEFAULT_MAX_DEPTH, DEFAULT_MIN_DEPTH
from semmap.limits import check, field_bounds
from semmap.maps.registry import MAPS, MapKind, own_rules
from semmap.maps.semantic_octomap import CellEvidence
from semmap.perception.instances.registry import INSTANCE_SOURCES, InstanceSourceName
from semmap.perception.registry import SEGMENTERS, SegmenterName, split_segmenter, split_structure
from semmap.poses.track import GROUND_TRUTH, POSE_SOURCES, PoseSource
from semmap.registry import check_name

#: Classes whose points only clear free space unless ``--dynamic`` says otherwise (people walk about).
DEFAULT_DYNAMIC: tuple[str, ...] = ("person",)


class ColorMode(str, Enum):
    """What colour an occupied voxel shows in the ``.ot`` file."""

    CLASS = "class"  # colour of the voxel's most probable class (falls back to RGB where it has none)
    RGB = "rgb"  # mean observed colour


class SemanticSource(str, Enum):
    """Where per-pixel class probabilities come from."""

    AUTO = "auto"  # frame labels (label PNGs, simulator ground truth) when present, else none
    LABELS = "labels"  # hard label images with a fixed confidence
    ORACLE = "oracle"  # simulated segmentation network made from ground-truth labels
    NONE = "none"  # geometry and colour only


class LoopMode(str, Enum):
    """How a run's frame loop gets its poses and semantics."""

    OFFLINE = "offline"  # track the whole sequence first, then map it with the tracker's final trajectory
    ONLINE = "online"  # map each frame as soon as the tracker has its pose; segment due frames beside tracking


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)  # NaN never reaches a kernel
    #: Where the section sits in a :class:`RunConfig` (``mapping``, ``input.ros``), for messages.
    section: ClassVar[str] = ""

    @model_validator(mode="before")
    @classmethod
    def _within_limits(cls, data: object) -> object:
        """Every field with a limit checked against ``semmap.limits`` before pydantic sees it: one
        :class:`ConfigError` naming the command-line option and the field (``--top-k (semantics.k) must be ...``)."""
        if isinstance(data, dict):
            for name, value in data.items():
                field = cls.model_fields.get(name)
                extra = field.json_schema_extra if field is not None else None
                if isinstance(extra, dict) and "limit" in extra:
                    check(str(extra["limit"]), value, _label(cls.section, name, extra.get("option")))
        return data


def _label(section: str, field: str, option: object) -> str:
    """``--option (section.field)``, or ``section.field`` for a field no option sets."""
    where = f"{section}.{field}" if section else field
    return f"{option} ({where})" if option else where


class RosConfig(_Section):
    """Topics and frames of a ROS bag (``datasets/rosbag.py``); None = found automatically where unambiguous."""

    section: ClassVar[str] = "input.ros"
    rgb_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    pose_topic: str | None = Field(None, description="PoseStamped / Odometry / TransformStamped topic (else /tf)")
    world_frame: str | None = Field(None, description="/tf frame of the world (default: the camera's root frame)")
    camera_frame: str | None = Field(None, description="/tf frame of the camera (default: the depth images' frame)")
    max_time_diff: float = Field(0.02, **field_bounds("time_diff"),
                                 description="largest colour/depth timestamp gap (s)")

    def options(self) -> dict:
        """Keyword arguments for :class:`semmap.datasets.rosbag.RosbagDataset`."""
        return self.model_dump()


class InputConfig(_Section):
    section: ClassVar[str] = "input"

    dataset: Path
    format: DatasetFormat = Field(DatasetFormat(AUTO), description=f"{FORMATS.choices((AUTO,))}")
    labels: Path | None = None
    stride: int = Field(1, **field_bounds("stride", "--stride"))
    max_frames: int | None = Field(None, **field_bounds("max_frames", "--max-frames"))
    raw_color: bool = Field(False, description="keep colour unregistered (7-Scenes colour is registered to depth)")
    ros: RosConfig = RosConfig()
    strict: bool = Field(False, description="stop at the first frame that cannot be used instead of skipping it")

    @field_validator("format", mode="before")
    @classmethod
    def _known_format(cls, v: object) -> object:
        return check_name(FORMATS, v, (AUTO,))


class MappingConfig(_Section):
    section: ClassVar[str] = "mapping"

    resolution: float = Field(0.05, **field_bounds("resolution", "--resolution"), description="finest voxel size (m)")
    min_depth: float = Field(DEFAULT_MIN_DEPTH, **field_bounds("min_depth", "--min-depth"))
    max_depth: float = Field(DEFAULT_MAX_DEPTH, **field_bounds("max_depth", "--max-depth"))
    max_range: float = Field(-1.0, **field_bounds("max_range", "--max-range"),
                             description="OctoMap max range (m); readings beyond only clear space; -1 = none")
    pixel_stride: int = Field(1, **field_bounds("pixel_stride", "--pixel-stride"),
                              description="use every k-th pixel row and column")
    prob_hit: float = Field(0.7, **field_bounds("probability"))
    prob_miss: float = Field(0.4, **field_bounds("probability"))
    clamp_min: float = Field(0.1192, **field_bounds("probability"))
    clamp_max: float = Field(0.971, **field_bounds("probability"))
    maps: tuple[MapKind, ...] = Field((MapKind.OCTOMAP,), min_length=1,
                                      description="maps built side by side; the first is the primary one")
    state_dtype: str | None = Field(None, pattern="^(float16|float32)$",
                                    description="per-class numbers of the voxel grid / point map (None: float32 / "
                                                "float16)")
    free_space: bool = Field(False, description="voxel grid: also ray-cast free space (occupancy OctoMap)")
    point_resolution: float = Field(0.01, **field_bounds("point_resolution", "--point-resolution"),
                                    description="filter cell of the point map (m)")
    cell_evidence: CellEvidence = Field(CellEvidence.MEAN, description="OctoMap: the class evidence a voxel takes "
                                        "from a frame: the mean of all its points' distributions (mean) or its first "
                                        "point's (first, OctoMap's discretized insert)")
    tsdf_voxel: float | None = Field(None, **field_bounds("resolution", "--tsdf-voxel"),
                                     description="voxel of the TSDF (m; None: the run's resolution)")
    tsdf_truncation: float = Field(4.0, **field_bounds("tsdf_truncation", "--tsdf-truncation"),
                                   description="TSDF truncation distance in voxels")
    decay: float = Field(0.0, **field_bounds("decay", "--decay"),
                         description="OctoMap (and the voxel grid's free space): share of log-odds a cell not "
                                     "observed in a frame loses towards unknown (0: none, OctoMap's update)")
    dynamic: tuple[str, ...] = Field(DEFAULT_DYNAMIC, description="dynamic classes (--dynamic): points whose most "
                                     "probable class is one of them only clear free space, never occupy a voxel")

    @field_validator("dynamic", mode="before")
    @classmethod
    def _class_names(cls, v: object) -> object:
        """``"person,chair"`` or a list of names; ``none`` (or nothing) for no dynamic class."""
        names = v.split(",") if isinstance(v, str) else v
        if isinstance(names, list | tuple):
            names = tuple(str(n).strip() for n in names if str(n).strip())
            return () if names in ((), ("none",)) else names
        return v

    @field_validator("maps", mode="before")
    @classmethod
    def _known_maps(cls, v: object) -> object:
        for name in v if isinstance(v, list | tuple) else ():
            check_name(MAPS, name)
        return v

    @field_validator("maps")
    @classmethod
    def _unique_maps(cls, v: tuple[MapKind, ...]) -> tuple[MapKind, ...]:
        if len(set(v)) != len(v):
            raise ValueError(f"each map at most once, got {[m.value for m in v]}")
        return v

    @field_validator("max_depth")
    @classmethod
    def _depth_range(cls, v: float, info) -> float:
        lo = info.data.get("min_depth", 0.0)
        if v <= lo:
            raise ValueError(f"max_depth ({v}) must exceed min_depth ({lo})")
        return v

    @model_validator(mode="after")
    def _decay_needs_free_space(self) -> MappingConfig:
        """``--decay`` fades free and occupied evidence: a map without an occupancy model has none to fade."""
        decays = MapKind.OCTOMAP in self.maps or (MapKind.VOXELGRID in self.maps and self.free_space)
        if self.decay > 0 and not decays:
            raise ValueError(f"--decay acts on the OctoMap and a voxel grid's free space (--free-space); --maps "
                             f"{','.join(m.value for m in self.maps)} has neither")
        return self


class SemanticsConfig(_Section):
    section: ClassVar[str] = "semantics"

    source: SemanticSource = SemanticSource.AUTO
    k: int = Field(3, **field_bounds("k", "--top-k"), description="classes kept per voxel")
    lam: float = Field(DEFAULT_LAMBDA, **field_bounds("lam", "--lambda"), description="penalty λ of Algorithm 1")
    max_confidence: float = Field(DEFAULT_MAX_CONFIDENCE, **field_bounds("confidence", "--max-confidence"))
    label_confidence: float = Field(0.9, **field_bounds("confidence", "--label-confidence"),
                                    description="confidence given to hard labels")
    temperature: float = Field(1.0, **field_bounds("temperature", "--temperature"),
                               description="class probabilities fused as softmax(logits / T) = p^(1/T) renormalised "
                                           "(> 1 softens an over-confident segmenter; 1: as given)")
    oracle_preset: str = "cnn-like"
    seed: int = Field(0, **field_bounds("seed"))
    segmenter: SegmenterName | None = Field(None, description=f"{SEGMENTERS.choices()} (None: from source)")
    add_structure: bool = Field(False, description="add wall, floor and ceiling from depth and gravity to the "
                                               "segmenter's classes (--segmenter NAME+structure)")
    up: str | None = Field(None, description="the world frame is gravity-aligned with this axis up (+z, -y, or "
                                             "x,y,z): the structure segmenter's up direction, carried by the poses")
    model: str | None = Field(None, description="the user's own model of --segmenter NAME:MODEL (an ONNX file, a "
                                                "Hugging Face model id or folder)")
    segmenter_config: Path | None = Field(None, description="JSON sidecar of an ONNX model (None: MODEL.json beside "
                                                            "it)")
    class_map: Path | None = Field(None, description="JSON mapping of a user model's classes to the map's labels "
                                                     "(a file, or a shipped one by name: ade20k-150, nyu40, "
                                                     "coco-panoptic-133)")
    weights: Path | None = Field(None, description="network weights, or the folder of precomputed predictions")
    trust_weights: bool = Field(False, description="use shipped weights whose sha256 differs from weights/manifest.json"
                                                   " (with a warning) instead of refusing them")
    calibration: bool = Field(True, description="apply the temperature stored with a trained network's weights "
                                                "(--no-calibration: raw softmax)")
    segment_every: int = Field(1, **field_bounds("segment_every", "--segment-every"),
                               description="segment every k-th frame")
    keyframes: bool = Field(False, description="segment only frames where the camera moved enough")
    batch_size: int = Field(1, **field_bounds("batch_size", "--batch-size"), description="frames per network batch")
    backend: str = Field("torch", pattern="^(torch|onnx)$", description="network runtime")
    fusion: FusionRule | None = Field(None, description=f"{' | '.join(r.value for r in FusionRule)} for every map "
                                                        f"(None: each map's own: {own_rules()})")
    class_prior: Path | None = Field(None, description="bayes-prior: JSON {class name: frequency} (None: uniform)")
    input_size: tuple[int, int] | int | None = Field(
        None, description="network input: (width, height), or the short side keeping the aspect ratio; None = the "
                    "segmenter's default (espnetv2: 320)")

    @field_validator("input_size", mode="before")
    @classmethod
    def _input_in_limits(cls, v: object) -> object:
        for side in (v if isinstance(v, list | tuple) else (v,)):
            check("input_side", side, _label(cls.section, "input_size", "--input-size"))
        return v

    @model_validator(mode="before")
    @classmethod
    def _model_after_colon(cls, data: object) -> object:
        """``segmenter = "onnx:MODEL.onnx"`` is read as the segmenter ``onnx`` and its ``model``; a ``+structure``
        suffix (``espnetv2+structure``) sets ``structure``."""
        if isinstance(data, dict) and isinstance(data.get("segmenter"), str):
            base, suffixed = split_structure(data["segmenter"])
            if suffixed:
                data = {**data, "segmenter": base, "add_structure": True}
            name, model = split_segmenter(data["segmenter"])
            if model is not None:
                if data.get("model") not in (None, model):
                    raise ValueError(f"two models: {model!r} (--segmenter) and {data['model']!r}")
                data = {**data, "segmenter": name, "model": model}
        return data

    @field_validator("segmenter", mode="before")
    @classmethod
    def _known_segmenter(cls, v: object) -> object:
        return check_name(SEGMENTERS, v)

    @field_validator("up", mode="before")
    @classmethod
    def _up_axis(cls, v: object) -> object:
        if v is not None:
            from semmap.perception.structure.gravity import parse_up

            try:
                parse_up(str(v))
            except ConfigError as exc:
                raise ValueError(str(exc)) from None
        return v

    @model_validator(mode="after")
    def _structure_needs_a_segmenter(self) -> SemanticsConfig:
        if self.add_structure and self.segmenter is None:
            raise ValueError("structure (+structure) needs a segmenter to add wall, floor and ceiling to")
        if self.add_structure and self.segmenter == SegmenterName.STRUCTURE:
            raise ValueError("structure+structure: name a network before +structure (espnetv2+structure)")
        return self

    @model_validator(mode="after")
    def _own_model_options(self) -> SemanticsConfig:
        """``--class-map`` and ``--segmenter-config`` act on the user's own model only: refused without one."""
        own = SEGMENTERS.where(takes_model=True)
        given = [o for o, v in (("--class-map", self.class_map), ("--segmenter-config", self.segmenter_config))
                 if v is not None]
        if given and (self.segmenter is None or self.segmenter not in own):
            named = "no --segmenter is given" if self.segmenter is None else f"--segmenter {self.segmenter} has none"
            raise ValueError(f"{' and '.join(given)} act{'s' if len(given) == 1 else ''} on the user's own model "
                             f"({', '.join(n + ':MODEL' for n in own)}); {named}")
        return self

    @field_validator("fusion", mode="before")
    @classmethod
    def _known_rule(cls, v: object) -> object:
        if v is not None and v not in {r.value for r in FusionRule}:
            raise ValueError(f"unknown fusion rule {v!r}; choose from {', '.join(r.value for r in FusionRule)}")
        return v


class PosesConfig(_Section):
    section: ClassVar[str] = "poses"

    source: PoseSource | Path = Field(PoseSource(GROUND_TRUTH), union_mode="left_to_right",
                                      description=f"{' | '.join(POSE_SOURCES)} | path of a TUM trajectory file")
    max_time_diff: float = Field(0.02, **field_bounds("time_diff"),
                                 description="largest timestamp gap when reading a trajectory file")


class OnlineConfig(_Section):
    """Bounds of an online run's frame loop (``mode = online``)."""

    section: ClassVar[str] = "online"
    max_pending: int = Field(8, **field_bounds("queue"),
                             description="frames waiting behind a frame still being segmented before "
                                         "tracking waits too")
    segment_queue: int = Field(2, **field_bounds("queue"), description="frames queued for or in segmentation at once")
    segment_threads: int = Field(1, **field_bounds("threads"),
                                 description="threads of the network runtime (ONNX Runtime / PyTorch)")
    segment_numba_threads: int = Field(1, **field_bounds("threads"),
                                       description="numba threads of the segmentation thread's kernels")
    read_ahead: int = Field(2, **field_bounds("queue"),
                            description="frames read (decoded, colour registered) ahead on a thread")
    rate: float | None = Field(None, **field_bounds("rate", "--rate"),
                               description="replay the frames at this many per second, as a live camera "
                                           "delivers them (latency counts from each frame's due time); "
                                           "None: as fast as the loop takes them")


_CRF = CrfParams()


class CrfConfig(_Section):
    """3D dense CRF over each map after integration (and every ``every`` keyframes while mapping)."""

    section: ClassVar[str] = "crf"
    enabled: bool = False
    every: int = Field(0, **field_bounds("every", "--crf-every"),
                       description="also refine every N keyframes during mapping (0: only at the end)")
    iterations: int = Field(5, **field_bounds("crf_iterations", "--crf-params"))
    appearance_weight: float = Field(_CRF.appearance_weight, **field_bounds("crf_weight", "--crf-params"),
                                     description="Potts weight of the position + colour kernel (SemanticFusion: 10)")
    appearance_position_std: float = Field(_CRF.appearance_position_std,
                                           **field_bounds("crf_position_std", "--crf-params"),
                                           description="its width in position (m; SemanticFusion: 0.05)")
    appearance_color_std: float = Field(_CRF.appearance_color_std, **field_bounds("crf_color_std", "--crf-params"),
                                        description="its width in colour (0-255; SemanticFusion: 20)")
    smoothness_weight: float = Field(_CRF.smoothness_weight, **field_bounds("crf_weight", "--crf-params"),
                                     description="Potts weight of the position + normal kernel (SemanticFusion: 3)")
    smoothness_position_std: float = Field(_CRF.smoothness_position_std,
                                           **field_bounds("crf_position_std", "--crf-params"),
                                           description="its width in position (m; SemanticFusion: 0.05)")
    smoothness_normal_std: float = Field(_CRF.smoothness_normal_std, **field_bounds("crf_normal_std", "--crf-params"),
                                         description="its width in unit-normal distance (SemanticFusion: 0.1)")

    def params(self) -> CrfParams:
        """The kernels and iterations as :class:`~semmap.fusion.crf.CrfParams`."""
        return CrfParams(**{key: getattr(self, key) for key in CRF_KEYS})


class OutputConfig(_Section):
    section: ClassVar[str] = "output"

    out: Path
    color_mode: ColorMode = ColorMode.CLASS
    preview: bool = True
    plots: bool = Field(True, description="draw the report's plots (trajectory, IoU, storage, timings)")
    cloud: bool = Field(False, description="write cloud.ply, the dense coloured point cloud of every frame's points "
                                           "voxel-filtered at mapping.point_resolution (the storage table's "
                                           "baseline); off by default: it costs a voxel-grid insertion per frame and "
                                           "a file of tens of MB")
    rerun: Path | None = Field(None, description="log the run to this rerun recording (.rrd)")
    rerun_spawn: bool = Field(False, description="stream the run to a rerun viewer")
    rerun_map_every: int = Field(10, **field_bounds("every_positive", "--rerun-map-every"),
                                 description="frames between two logs of the whole map")


class ObjectsConfig(_Section):
    section: ClassVar[str] = "objects"

    instances: InstanceSourceName | None = Field(None, description=f"{INSTANCE_SOURCES.choices()}: build the object "
                                                                   "map (None: no)")
    weights: Path | None = Field(None, description="Mask R-CNN state dict (--instances maskrcnn)")
    errors: str = Field("maskrcnn-like", description="oracle instances' error preset: exact | maskrcnn-like | noisy")
    seed: int = Field(0, **field_bounds("seed"))

    @field_validator("instances", mode="before")
    @classmethod
    def _known_source(cls, v: object) -> object:
        return check_name(INSTANCE_SOURCES, v)


class RunConfig(_Section):
    """Everything one ``semmap run`` needs."""

    input: InputConfig
    mapping: MappingConfig = MappingConfig()
    semantics: SemanticsConfig = SemanticsConfig()
    poses: PosesConfig = PosesConfig()
    mode: LoopMode = LoopMode.OFFLINE
    online: OnlineConfig = OnlineConfig()
    crf: CrfConfig = CrfConfig()
    objects: ObjectsConfig = ObjectsConfig()
    output: OutputConfig

    @model_validator(mode="after")
    def _rate_needs_online(self) -> RunConfig:
        if self.online.rate is not None and self.mode != LoopMode.ONLINE:
            raise ValueError("a replay rate (--rate) needs an online run (--online): offline, frames are not "
                             "taken as they arrive")
        return self

    def to_json(self) -> str:
        return self.model_dump_json(indent=2)
