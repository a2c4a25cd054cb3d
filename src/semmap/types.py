"""The small data types every stage speaks: frames, intrinsics, label sets, class probabilities, SE(3).

Conventions: poses are ``T_world_cam`` 4x4 float64 (camera x right, y down, z forward), metres everywhere,
label 0 is "unknown / void" in every :class:`LabelSet`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError, DatasetError
from semmap.files.atomic import write_text_atomic
from semmap.files.safe import read_text_limited

#: Sentinel label id for an unused slot in a top-k semantic set.
EMPTY_LABEL = np.uint16(65535)


# --------------------------------------------------------------------------------------------------
# Camera
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of a depth-registered RGB-D camera (pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ConfigError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (np.isfinite([self.fx, self.fy, self.cx, self.cy]).all() and self.fx > 0 and self.fy > 0):
            raise ConfigError(f"camera focal lengths must be finite and positive, got fx={self.fx} fy={self.fy}")

    @property
    def K(self) -> np.ndarray:
        """3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_matrix(cls, K: np.ndarray, width: int, height: int) -> CameraIntrinsics:
        K = np.asarray(K, dtype=np.float64)
        return cls(width, height, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))

    def scaled(self, factor: float) -> CameraIntrinsics:
        """Intrinsics of the image resized by ``factor`` (pixel-centre convention)."""
        return CameraIntrinsics(
            round(self.width * factor),
            round(self.height * factor),
            self.fx * factor,
            self.fy * factor,
            (self.cx + 0.5) * factor - 0.5,
            (self.cy + 0.5) * factor - 0.5,
        )

    def to_dict(self) -> dict:
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
                "cx": self.cx, "cy": self.cy}

    @classmethod
    def from_dict(cls, d: dict) -> CameraIntrinsics:
        try:
            return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]),
                       float(d["cx"]), float(d["cy"]))
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise ConfigError(f"camera intrinsics need width, height, fx, fy, cx, cy: {exc}") from exc


#: Default camera: Kinect-like 640x480 with TUM's default calibration (the simulator's camera, and a TUM sequence's
#: focal lengths and centre when neither ``camera.json`` nor the folder's Freiburg name says otherwise).
DEFAULT_INTRINSICS = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


# --------------------------------------------------------------------------------------------------
# Labels
# --------------------------------------------------------------------------------------------------
def muted_grey(rgb: np.ndarray) -> np.ndarray:
    """Grey of (N, 3) uint8 colours (luminance squeezed into 64..192), for voxels without a real class in
    class-coloured views: the scene stays readable while only classified things show colour."""
    lum = np.asarray(rgb, np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    grey = (64.0 + lum * (128.0 / 255.0)).astype(np.uint8)
    return np.repeat(grey[:, None], 3, axis=1)


@dataclass(frozen=True)
class LabelSet:
    """Class names and display colours, indexed by class id; id 0 is "unknown / void".

    Colours are never pure white: OctoMap's ColorOcTree treats (255, 255, 255) as "colour not set".
    """

    names: tuple[str, ...]
    colors: np.ndarray = field(repr=False)  # (K, 3) uint8

    def __post_init__(self) -> None:
        colors = np.asarray(self.colors, dtype=np.uint8).reshape(-1, 3)
        if len(self.names) == 0:
            raise ConfigError("a label set needs at least the 'unknown' class")
        if colors.shape[0] != len(self.names):
            raise ConfigError(f"label set has {len(self.names)} names but {colors.shape[0]} colours")
        if len(self.names) >= int(EMPTY_LABEL):
            raise ConfigError(f"at most {int(EMPTY_LABEL) - 1} classes are supported")
        white = np.all(colors == 255, axis=1)
        if white.any():
            colors = colors.copy()
            colors[white] = (254, 254, 254)
        colors.setflags(write=False)
        object.__setattr__(self, "colors", colors)

    def __len__(self) -> int:
        return len(self.names)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LabelSet):
            return NotImplemented
        return self.names == other.names and np.array_equal(self.colors, other.colors)

    def __hash__(self) -> int:
        return hash((self.names, self.colors.tobytes()))

    @property
    def ids(self) -> np.ndarray:
        return np.arange(len(self.names), dtype=np.uint16)

    def id_of(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ConfigError(f"unknown class name {name!r}; known: {', '.join(self.names)}") from None

    def colorize(self, labels: np.ndarray) -> np.ndarray:
        """Class-colour image (…, 3) uint8 for an integer label array; ids out of range become black."""
        labels = np.asarray(labels)
        lut = np.zeros((max(int(labels.max(initial=0)) + 1, len(self)), 3), np.uint8)
        lut[: len(self)] = self.colors
        return lut[labels]

    def to_dict(self) -> dict:
        return {"classes": [{"id": i, "name": n, "color": [int(c) for c in self.colors[i]]}
                            for i, n in enumerate(self.names)]}

    @classmethod
    def from_dict(cls, d: dict) -> LabelSet:
        try:
            entries = sorted(d["classes"], key=lambda e: int(e["id"]))
            ids = [int(e["id"]) for e in entries]
            if ids != list(range(len(ids))):
                raise ValueError("class ids must be 0..K-1 without gaps")
            return cls(tuple(str(e["name"]) for e in entries),
                       np.array([e["color"] for e in entries], dtype=np.uint8))
        except (KeyError, TypeError, ValueError, OverflowError, AttributeError) as exc:
            raise ConfigError(f"malformed label set: {exc}") from exc

    def save(self, path: str | Path) -> None:
        write_text_atomic(path, json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> LabelSet:
        text = read_text_limited(path, what="label set", error=lambda reason: DatasetError(f"{path}: {reason}"))
        try:
            return cls.from_dict(json.loads(text))
        except (json.JSONDecodeError, AttributeError) as exc:
            raise DatasetError(f"{path}: cannot read label set: {exc}") from exc
        except ConfigError as exc:
            raise DatasetError(f"{path}: {exc}") from exc

    @classmethod
    def generic(cls, num_classes: int) -> LabelSet:
        """Label set with ``num_classes`` ids named ``class_i`` and well-spread colours (0 = unknown)."""
        names = ("unknown", *tuple(f"class_{i}" for i in range(1, num_classes)))
        return cls(names, distinct_colors(num_classes))


def distinct_colors(n: int) -> np.ndarray:
    """``n`` well-separated, deterministic, never-white colours; colour 0 is black (unknown)."""
    colors = np.zeros((n, 3), np.uint8)
    golden = 0.618033988749895
    for i in range(1, n):
        h = (i * golden) % 1.0
        s = 0.65 + 0.35 * ((i * 7) % 3) / 2
        v = 0.95 - 0.3 * ((i * 5) % 4) / 3
        colors[i] = _hsv_to_rgb(h, s, v)
    return colors


def _hsv_to_rgb(h: float, s: float, v: float) -> tuple[int, int, int]:
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    r, g, b = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]
    return int(r * 255), int(g * 255), int(b * 255)


# --------------------------------------------------------------------------------------------------
# Class probabilities
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TopKProbs:
    """Per-pixel (or per-point) top-k class distribution; the missing mass is the "others" class.

    ``labels`` (..., k) uint16 with :data:`EMPTY_LABEL` in unused slots, ``probs`` (..., k) float32,
    sorted by decreasing probability; ``others = 1 - probs.sum(-1)``.
    """

    labels: np.ndarray
    probs: np.ndarray

    def __post_init__(self) -> None:
        if self.labels.shape != self.probs.shape:
            raise ConfigError(f"top-k labels {self.labels.shape} and probs {self.probs.shape} differ in shape")

    @property
    def k(self) -> int:
        return int(self.labels.shape[-1])

    @property
    def others(self) -> np.ndarray:
        return np.clip(1.0 - self.probs.sum(-1), 0.0, 1.0).astype(np.float32)

    def argmax(self) -> np.ndarray:
        return self.labels[..., 0]

    def reshape_flat(self) -> TopKProbs:
        """View as (N, k) rows, e.g. one per pixel."""
        return TopKProbs(self.labels.reshape(-1, self.k), self.probs.reshape(-1, self.k))

    @classmethod
    def from_dense(cls, probs: np.ndarray, k: int = 3) -> TopKProbs:
        """Top-``k`` of a dense (..., K) probability array (ties broken by the lower class id)."""
        probs = np.asarray(probs)
        K = probs.shape[-1]
        k_eff = min(k, K)
        flat = probs.reshape(-1, K).astype(np.float32)
        # stable descending order: sort on (-p, id)
        order = np.argsort(-flat, axis=1, kind="stable")[:, :k_eff]
        top_p = np.take_along_axis(flat, order, axis=1)
        labels = np.full((flat.shape[0], k), EMPTY_LABEL, np.uint16)
        out_p = np.zeros((flat.shape[0], k), np.float32)
        labels[:, :k_eff] = order
        out_p[:, :k_eff] = top_p
        shape = (*probs.shape[:-1], k)
        return cls(labels.reshape(shape), out_p.reshape(shape))

    @classmethod
    def from_hard_labels(cls, labels: np.ndarray, confidence: float, num_classes: int, k: int = 3) -> TopKProbs:
        """Distribution for a hard label map: ``confidence`` on the given class, the rest in "others"."""
        if not 0.0 < confidence <= 1.0:
            raise ConfigError(f"label confidence must be in (0, 1], got {confidence}")
        labels = np.asarray(labels)
        if labels.size and int(labels.max()) >= num_classes:
            raise ConfigError(f"label id {int(labels.max())} is outside the label set (0..{num_classes - 1})")
        out_l = np.full((*labels.shape, k), EMPTY_LABEL, np.uint16)
        out_p = np.zeros((*labels.shape, k), np.float32)
        out_l[..., 0] = labels
        out_p[..., 0] = confidence
        return cls(out_l, out_p)


# --------------------------------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ColorCamera:
    """A colour camera beside the depth camera: its pinhole intrinsics (pixels of the colour image) and where a
    point of the depth camera's frame lands in its frame, ``X_color = X_depth + t_color_depth`` (no rotation)."""

    fx: float
    fy: float
    cx: float
    cy: float
    t_color_depth: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class RawColor:
    """A frame's colour image as its own camera took it, kept where ``Frame.rgb`` was resampled onto the depth
    camera: segmentation networks see the whole, unresampled view and their output is carried onto the depth grid
    (:func:`semmap.geometry.onto_depth_grid`)."""

    image: np.ndarray  # (h, w, 3) uint8
    camera: ColorCamera


@dataclass(frozen=True)
class Frame:
    """One registered RGB-D frame and whatever ground truth or perception came with it.

    ``depth`` is float32 metres with 0 for invalid; ``T_world_cam`` is None when the source has no pose.
    """

    index: int
    timestamp: float
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres, 0 = invalid
    intrinsics: CameraIntrinsics
    T_world_cam: np.ndarray | None = None  # (4, 4) float64
    labels: np.ndarray | None = None  # (H, W) uint16 class ids, 0 = unknown
    instances: np.ndarray | None = None  # (H, W) int32 instance ids, 0 = none
    semantics: TopKProbs | None = None  # (H, W, k) per-pixel class distribution
    name: str = ""
    raw_color: RawColor | None = None  # the colour camera's own image, where rgb was registered onto depth
    up_cam: np.ndarray | None = None  # (3,) unit up direction in the camera frame, from the sensor's accelerometer

    def __post_init__(self) -> None:
        h, w = self.intrinsics.height, self.intrinsics.width
        where = f"frame {self.name or self.index}"
        if self.rgb.shape != (h, w, 3) or self.rgb.dtype != np.uint8:
            raise DatasetError(f"{where}: colour image is {self.rgb.shape} {self.rgb.dtype}, "
                               f"expected ({h}, {w}, 3) uint8")
        if self.depth.shape != (h, w) or self.depth.dtype != np.float32:
            raise DatasetError(f"{where}: depth image is {self.depth.shape} {self.depth.dtype}, "
                               f"expected ({h}, {w}) float32")
        for what, arr in (("labels", self.labels), ("instances", self.instances)):
            if arr is not None and arr.shape != (h, w):
                raise DatasetError(f"{where}: {what} image is {arr.shape}, expected ({h}, {w})")
        if self.semantics is not None and self.semantics.labels.shape[:2] != (h, w):
            raise DatasetError(f"{where}: class probabilities are {self.semantics.labels.shape[:2]}, "
                               f"expected ({h}, {w})")
        if self.T_world_cam is not None:
            check_pose(self.T_world_cam, where)
        if self.up_cam is not None:
            up = np.asarray(self.up_cam, np.float64)
            if up.shape != (3,) or not np.isfinite(up).all() or not 0.5 < float(np.linalg.norm(up)) < 1.5:
                raise DatasetError(f"{where}: up direction {up.tolist()} is not a unit 3-vector")
        if self.raw_color is not None and (self.raw_color.image.ndim != 3 or self.raw_color.image.shape[2] != 3
                                           or self.raw_color.image.dtype != np.uint8):
            raise DatasetError(f"{where}: raw colour image is {self.raw_color.image.shape} "
                               f"{self.raw_color.image.dtype}, expected (h, w, 3) uint8")

    def with_(self, **changes) -> Frame:
        """Copy with some fields replaced (frames are immutable)."""
        from dataclasses import replace

        return replace(self, **changes)


# --------------------------------------------------------------------------------------------------
# Maps
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Observation:
    """One frame's evidence as every map integrates it: world points with the colour, class distribution,
    normal and instance of their pixel, and the sensor origin the rays start from.

    ``semantics`` is None on frames that were not segmented (they still add geometry and colour);
    ``normals`` is filled only when a map asks for them (``needs_normals``); ``clear_points`` are the points of
    dynamic classes (people): their rays clear free space, but they add no hit, colour or class to any map.
    """

    points_world: np.ndarray  # (N, 3) float32 metres, world frame
    origin: np.ndarray  # (3,) float64 sensor centre in the world frame
    colors: np.ndarray  # (N, 3) uint8
    semantics: TopKProbs | None = None  # (N, k) per-point class distribution
    normals: np.ndarray | None = None  # (N, 3) float32 unit normals, world frame, facing the sensor
    instances: np.ndarray | None = None  # (N,) int32 instance id of each point's pixel, 0 = none
    frame_index: int = 0
    keyframe: bool = True  # the camera moved enough since the last keyframe (maps may update only then)
    clear_points: np.ndarray | None = None  # (M, 3) float32 world points whose rays only clear (dynamic classes)

    def __post_init__(self) -> None:
        n = self.points_world.shape[0]
        if self.points_world.ndim != 2 or self.points_world.shape[1] != 3:
            raise ConfigError(f"observation points must be (N, 3), got {self.points_world.shape}")
        for what, arr, tail in (("colours", self.colors, (3,)), ("normals", self.normals, (3,)),
                                ("instances", self.instances, ())):
            if arr is not None and arr.shape != (n, *tail):
                raise ConfigError(f"observation {what} must be {(n, *tail)}, got {arr.shape}")
        if self.clear_points is not None and (self.clear_points.ndim != 2 or self.clear_points.shape[1] != 3):
            raise ConfigError(f"observation clear-only points must be (M, 3), got {self.clear_points.shape}")
        if self.semantics is not None and self.semantics.labels.shape[0] != n:
            raise ConfigError(f"observation class sets cover {self.semantics.labels.shape[0]} points, not {n}")

    def __len__(self) -> int:
        return int(self.points_world.shape[0])


@dataclass(frozen=True)
class MapCloud:
    """A map's occupied voxels or points as flat arrays (for evaluation, previews, viewers and PLY files)."""

    centers: np.ndarray  # (M, 3) float64 metres, world frame
    colors: np.ndarray  # (M, 3) uint8 mean observed colour (grey where never coloured)
    labels: np.ndarray  # (M,) uint16 most probable class, EMPTY_LABEL where none
    confidence: np.ndarray  # (M,) float32 probability of that class (0 where none)
    resolution: float  # voxel edge, or the filter cell of a point map (metres)
    normals: np.ndarray | None = None  # (M, 3) float32 where the map keeps normals

    def __len__(self) -> int:
        return int(self.centers.shape[0])


# --------------------------------------------------------------------------------------------------
# SE(3)
# --------------------------------------------------------------------------------------------------
def check_pose(T: np.ndarray, where: str = "pose") -> np.ndarray:
    """Validate a 4x4 rigid transform; raise :class:`DatasetError` naming ``where`` otherwise."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise DatasetError(f"{where}: pose must be 4x4, got {T.shape}")
    if not np.isfinite(T).all():
        raise DatasetError(f"{where}: pose has non-finite entries")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        raise DatasetError(f"{where}: pose is not a rigid transform (rotation not orthonormal)")
    return T


def make_pose(R: np.ndarray, t: Sequence[float] | np.ndarray) -> np.ndarray:
    """4x4 transform from a 3x3 rotation and a translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform, or of each of a stack (..., 4, 4), without a general matrix inverse."""
    T = np.asarray(T, dtype=np.float64)
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def rot_z(yaw: np.ndarray | float) -> np.ndarray:
    """Rotation (3, 3) about z by ``yaw`` radians, or a stack (..., 3, 3) for an array of angles."""
    yaw = np.asarray(yaw, np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((*yaw.shape, 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 2, 2] = 1.0
    return out


def orthonormality_error(R: np.ndarray) -> float:
    """max |R Rᵀ − I| of a 3x3 matrix (0 for an exact rotation)."""
    R = np.asarray(R, dtype=np.float64)
    return float(np.abs(R @ R.T - np.eye(3)).max())


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to a 3x3 matrix, via SVD; a reflection is turned into a rotation."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def snap_rigid(T: np.ndarray) -> np.ndarray:
    """4x4 ``T`` with its rotation snapped back to the nearest proper one and the bottom row exact (chained
    products drift, and Open3D works in float32); a non-finite ``T`` is returned as it is, for the caller to reject."""
    if not np.isfinite(T).all():
        return T
    out = np.array(T, dtype=np.float64)
    out[:3, :3] = orthonormalize(T[:3, :3])
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return out


def rotation_angle(R: np.ndarray) -> float:
    """Angle (radians) of a rotation matrix (or the rotation of a 4x4 transform), from atan2 of its skew and
    symmetric parts: exact for small angles and blind to slight non-orthonormality, where arccos of the trace
    reads 3e-4 of drift (7-Scenes' ground truth) as a 1 degree turn."""
    R = np.asarray(R, np.float64)[:3, :3]
    skew = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(np.arctan2(0.5 * np.linalg.norm(skew), 0.5 * (np.trace(R) - 1.0)))


def pose_change(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Translation (metres) and rotation (degrees) from pose ``T_a`` to pose ``T_b``."""
    rel = invert_pose(T_a) @ T_b
    return float(np.linalg.norm(rel[:3, 3])), float(np.degrees(rotation_angle(rel)))


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points; keeps float32 input as float32 (computed in float64)."""
    pts = np.asarray(points)
    out = pts.astype(np.float64, copy=False) @ T[:3, :3].T + T[:3, 3]
    return out.astype(pts.dtype if pts.dtype in (np.float32, np.float64) else np.float64)


def quat_xyzw_to_rot(q: Sequence[float] | np.ndarray) -> np.ndarray:
    """Rotation matrix from a quaternion in TUM order (qx, qy, qz, qw); normalises the input."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rot_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Quaternion (qx, qy, qz, qw) with qw >= 0 from a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def pose_from_tum(values: Sequence[float]) -> np.ndarray:
    """``T_world_cam`` from a TUM row ``tx ty tz qx qy qz qw``."""
    v = np.asarray(values, dtype=np.float64)
    return make_pose(quat_xyzw_to_rot(v[3:7]), v[:3])


def pose_to_tum(T: np.ndarray) -> np.ndarray:
    """TUM row ``tx ty tz qx qy qz qw`` for a 4x4 transform."""
    return np.concatenate([T[:3, 3], rot_to_quat_xyzw(T[:3, :3])])


def poses_from_tum(rows: np.ndarray) -> np.ndarray:
    """(N, 4, 4) ``T_world_cam`` from (N, 7) TUM rows, all at once (:func:`pose_from_tum` row by row)."""
    v = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
    # each row's norm as pose_from_tum takes it (a vector norm rounds unlike an axis norm): the same bits
    norms = np.fromiter((np.linalg.norm(r) for r in v[:, 3:7]), np.float64, len(v))
    q = v[:, 3:7] / norms[:, None]
    x, y, z, w = q.T
    out = np.zeros((len(v), 4, 4))
    out[:, 0] = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w), v[:, 0]], 1)
    out[:, 1] = np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w), v[:, 1]], 1)
    out[:, 2] = np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y), v[:, 2]], 1)
    out[:, 3, 3] = 1.0
    return out


def tum_rows(poses: np.ndarray) -> np.ndarray:
    """(N, 7) TUM rows of (N, 4, 4) transforms, all at once, bit for bit :func:`pose_to_tum` row by row (the same
    branches of Shepperd's method, qw >= 0)."""
    T = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    R = T[:, :3, :3]
    r00, r11, r22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    tr = np.trace(R, axis1=1, axis2=2)
    q = np.empty((len(T), 4))
    taken = np.zeros(len(T), bool)
    for k, case in enumerate([tr > 0, (r00 > r11) & (r00 > r22), r11 > r22, np.ones(len(T), bool)]):
        m = case & ~taken
        taken |= m
        a = R[m]
        if k == 0:
            s = np.sqrt(tr[m] + 1.0) * 2
            q[m] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / s, (a[:, 0, 2] - a[:, 2, 0]) / s,
                             (a[:, 1, 0] - a[:, 0, 1]) / s, 0.25 * s], 1)
        elif k == 1:
            s = np.sqrt(1.0 + a[:, 0, 0] - a[:, 1, 1] - a[:, 2, 2]) * 2
            q[m] = np.stack([0.25 * s, (a[:, 0, 1] + a[:, 1, 0]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s,
                             (a[:, 2, 1] - a[:, 1, 2]) / s], 1)
        elif k == 2:
            s = np.sqrt(1.0 + a[:, 1, 1] - a[:, 0, 0] - a[:, 2, 2]) * 2
            q[m] = np.stack([(a[:, 0, 1] + a[:, 1, 0]) / s, 0.25 * s, (a[:, 1, 2] + a[:, 2, 1]) / s,
                             (a[:, 0, 2] - a[:, 2, 0]) / s], 1)
        else:
            s = np.sqrt(1.0 + a[:, 2, 2] - a[:, 0, 0] - a[:, 1, 1]) * 2
            q[m] = np.stack([(a[:, 0, 2] + a[:, 2, 0]) / s, (a[:, 1, 2] + a[:, 2, 1]) / s, 0.25 * s,
                             (a[:, 1, 0] - a[:, 0, 1]) / s], 1)
    q /= np.fromiter((np.linalg.norm(r) for r in q), np.float64, len(q))[:, None]  # as pose_to_tum rounds
    q[q[:, 3] < 0] *= -1
    return np.concatenate([T[:, :3, 3], q], axis=1)


def slerp(q0: np.ndarray, q1: np.ndarray, alpha: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (xyzw), shortest path."""
    q0 = np.asarray(q0, float) / np.linalg.norm(q0)
    q1 = np.asarray(q1, float) / np.linalg.norm(q1)
    dot = float(q0 @ q1)
    if dot < 0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + alpha * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    return (np.sin((1 - alpha) * theta) * q0 + np.sin(alpha * theta) * q1) / np.sin(theta)


def interpolate_pose(T0: np.ndarray, T1: np.ndarray, alpha: float) -> np.ndarray:
    """Pose at fraction ``alpha`` between T0 and T1: linear in translation, slerp in rotation."""
    q = slerp(rot_to_quat_xyzw(T0[:3, :3]), rot_to_quat_xyzw(T1[:3, :3]), alpha)
    t = (1 - alpha) * T0[:3, 3] + alpha * T1[:3, 3]
    return make_pose(quat_xyzw_to_rot(q), t)



# --------------------------------------------------------------------------------------------------
# Trajectories
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Trajectory:
    """Timestamped camera poses ``T_world_cam``, as a pose source produces and ``trajectory.txt`` stores.

    ``names`` (optional, one per pose) ties poses to dataset frames; timestamps are strictly increasing.
    """

    timestamps: np.ndarray  # (N,) float64 seconds
    poses: np.ndarray  # (N, 4, 4) float64
    names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        t = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        p = np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4)
        if len(t) != len(p):
            raise ConfigError(f"trajectory has {len(t)} timestamps but {len(p)} poses")
        if self.names and len(self.names) != len(t):
            raise ConfigError(f"trajectory has {len(t)} poses but {len(self.names)} names")
        if len(t) > 1 and not (np.diff(t) > 0).all():
            raise ConfigError("trajectory timestamps must be strictly increasing")
        object.__setattr__(self, "timestamps", t)
        object.__setattr__(self, "poses", p)
        object.__setattr__(self, "names", tuple(self.names))

    def __len__(self) -> int:
        return len(self.timestamps)

    @classmethod
    def from_rows(cls, rows: list[tuple[float, str, np.ndarray]]) -> Trajectory:
        """A trajectory from ``(timestamp, frame name, T_world_cam)`` rows in any order (sorted by time)."""
        rows = sorted(rows, key=lambda r: r[0])
        return cls(np.array([r[0] for r in rows], np.float64), np.array([r[2] for r in rows]).reshape(-1, 4, 4),
                   tuple(r[1] for r in rows))

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) camera centres in the world frame."""
        return self.poses[:, :3, 3]


# --------------------------------------------------------------------------------------------------
# Object instances
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Instances:
    """Object instances found in one frame, as an instance source hands them to the tracker and the object map.

    ``ids`` (H, W) int32 is 0 where there is no instance and ``i + 1`` on detection ``i``'s mask (masks never
    overlap); per detection ``class_ids`` (N,) int32 (of the source's label set), ``scores`` (N,) float32,
    ``boxes`` (N, 4) float32 pixel extents ``x0, y0, x1, y1`` (inclusive), optional ``features`` (N, D) float32
    unit-length appearance descriptors, and ``track_ids`` (N,) int32 once a tracker has named them (0 = none).
    """

    ids: np.ndarray
    class_ids: np.ndarray
    scores: np.ndarray
    boxes: np.ndarray
    features: np.ndarray | None = None
    track_ids: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.class_ids)
        if self.ids.ndim != 2:
            raise ConfigError(f"instance id image must be 2-D, got shape {self.ids.shape}")
        if len(self.scores) != n or self.boxes.shape != (n, 4):
            raise ConfigError(f"instances: {n} classes but {len(self.scores)} scores and boxes {self.boxes.shape}")
        for what, arr in (("features", self.features), ("track ids", self.track_ids)):
            if arr is not None and len(arr) != n:
                raise ConfigError(f"instances: {n} detections but {len(arr)} {what}")

    def __len__(self) -> int:
        return len(self.class_ids)

    @property
    def pixel_counts(self) -> np.ndarray:
        """(N,) int64 mask sizes in pixels."""
        return np.bincount(self.ids.ravel(), minlength=len(self) + 1)[1:len(self) + 1]

    def with_(self, **changes) -> Instances:
        """Copy with some fields replaced."""
        from dataclasses import replace

        return replace(self, **changes)

    @classmethod
    def empty(cls, height: int, width: int) -> Instances:
        return cls(np.zeros((height, width), np.int32), np.zeros(0, np.int32), np.zeros(0, np.float32),
                   np.zeros((0, 4), np.float32))

    @classmethod
    def from_id_image(cls, ids: np.ndarray, class_ids: np.ndarray, scores: np.ndarray,
                      features: np.ndarray | None = None) -> Instances:
        """Instances of an id image (0 = none, i + 1 = detection i) with boxes measured from the masks;
        detections whose mask is empty are dropped and the rest renumbered."""
        ids = np.ascontiguousarray(ids, np.int32)
        class_ids = np.asarray(class_ids, np.int32).reshape(-1)
        scores = np.asarray(scores, np.float32).reshape(-1)
        n = len(class_ids)
        if ids.size and int(ids.max()) > n:
            raise ConfigError(f"instance id image names detection {int(ids.max())} but only {n} are given")
        boxes, present = mask_boxes(ids, n)
        if not present.all():
            renumber = np.zeros(n + 1, np.int32)
            renumber[1:][present] = np.arange(1, int(present.sum()) + 1, dtype=np.int32)
            ids = renumber[ids]
            class_ids, scores, boxes = class_ids[present], scores[present], boxes[present]
            features = None if features is None else features[present]
        return cls(ids, class_ids, scores, boxes, None if features is None else np.asarray(features, np.float32))


def mask_boxes(ids: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel extents (n, 4) float32 ``x0, y0, x1, y1`` (inclusive) of masks 1..n of an id image, and which
    masks are non-empty (one C pass, ``scipy.ndimage.find_objects``)."""
    from scipy.ndimage import find_objects

    boxes = np.zeros((n, 4), np.float32)
    present = np.zeros(n, bool)
    if n == 0:
        return boxes, present
    for i, sl in enumerate(find_objects(np.asarray(ids, np.int32), max_label=n)):
        if sl is not None:
            present[i] = True
            boxes[i] = (sl[1].start, sl[0].start, sl[1].stop - 1, sl[0].stop - 1)
    return boxes, present
