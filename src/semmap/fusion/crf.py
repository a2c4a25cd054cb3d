"""3D fully connected CRF over a map's voxels or points (SemanticFusion / *rgbd-semantic-mapping-multiscale-crf*).

Unaries are the fused class distributions, ``-log p(c)``; pairwise terms are Potts with two Gaussian kernels over
the elements, as SemanticFusion uses on its surfels:

- appearance: ``w_a exp(-|p_i - p_j|^2 / 2 θ_a^2 - |I_i - I_j|^2 / 2 θ_β^2)`` (position + colour);
- smoothness: ``w_s exp(-|p_i - p_j|^2 / 2 θ_γ^2 - |n_i - n_j|^2 / 2 θ_δ^2)`` (position + normal).

Mean-field inference with the permutohedral lattice of ``pydensecrf`` (custom features, ``DenseCRF(N, K)``);
maps without normals get them from their elements' neighbourhoods (Open3D, oriented towards a viewpoint).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, fields

import numpy as np

from semmap.errors import ConfigError
from semmap.limits import check_crf
from semmap.types import EMPTY_LABEL


@dataclass(frozen=True)
class CrfParams:
    """Kernel widths (metres, colour units 0-255, unit-normal distance), Potts weights, mean-field iterations.

    The defaults were tuned on simulated scenes at 5 cm voxels: SemanticFusion's appearance weight (10, the best of
    the sweep on three scenes) with wider kernels and a lighter smoothness than its surfels'
    (:data:`SEMANTICFUSION`; docs/EXPERIMENTS.md measures both)."""

    iterations: int = 5
    appearance_weight: float = 10.0
    appearance_position_std: float = 0.15
    appearance_color_std: float = 20.0
    smoothness_weight: float = 2.0
    smoothness_position_std: float = 0.06
    smoothness_normal_std: float = 0.3

    def __post_init__(self) -> None:
        if self.iterations < 1:
            raise ConfigError(f"CRF iterations must be >= 1, got {self.iterations}")
        stds = (self.appearance_position_std, self.appearance_color_std, self.smoothness_position_std,
                self.smoothness_normal_std)
        if min(stds) <= 0 or min(self.appearance_weight, self.smoothness_weight) < 0:
            raise ConfigError("CRF kernel widths must be positive and weights non-negative")


#: SemanticFusion's CRF over surfels (McCormac et al. 2017): appearance weight 10 with 0.05 m and colour 20,
#: smoothness weight 3 with 0.05 m and normals 0.1.
SEMANTICFUSION = CrfParams(appearance_weight=10.0, appearance_position_std=0.05, appearance_color_std=20.0,
                           smoothness_weight=3.0, smoothness_position_std=0.05, smoothness_normal_std=0.1)
#: The keys of ``--crf-params`` (the fields of :class:`CrfParams`), and the named sets of values it accepts.
CRF_KEYS: tuple[str, ...] = tuple(f.name for f in fields(CrfParams))
CRF_PRESETS: dict[str, CrfParams] = {"default": CrfParams(), "semanticfusion": SEMANTICFUSION}


def parse_crf_params(text: str | None, option: str = "--crf-params") -> dict[str, float | int]:
    """``"appearance_weight=10,smoothness_normal_std=0.1"`` -> ``{key: number}`` (a preset name among the items
    sets all keys first: ``"semanticfusion,iterations=10"``); ranges are checked by the configuration. An
    unknown key, a missing ``=`` or a non-number is refused in one :class:`ConfigError` line naming ``option``."""
    out: dict[str, float | int] = {}
    for item in (text or "").split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            if item.lower() not in CRF_PRESETS:
                raise ConfigError(f"{option}: {item!r} is neither key=value nor a preset "
                                  f"({' | '.join(CRF_PRESETS)}); keys: {', '.join(CRF_KEYS)}")
            out.update(asdict(CRF_PRESETS[item.lower()]))
            continue
        key, value = (part.strip() for part in item.split("=", 1))
        key = key.replace("-", "_")
        if key not in CRF_KEYS:
            raise ConfigError(f"{option}: unknown key {key!r}; keys: {', '.join(CRF_KEYS)}")
        try:
            number = float(value)
        except ValueError:
            raise ConfigError(f"{option}: {key} must be a number, got {value!r}") from None
        out[key] = int(number) if key == "iterations" and number.is_integer() else number
    return out


@dataclass(frozen=True)
class CrfResult:
    """Which elements were refined and how long it took."""

    refined: int  # elements with class evidence that took part
    changed: int  # of those, elements whose most probable class changed
    ms: float


def estimate_normals(points: np.ndarray, radius: float, viewpoint: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) float32 unit normals of a point set from its neighbourhoods (PCA within ``radius``, at most 30
    neighbours), oriented towards ``viewpoint`` (default: the centroid, which faces a room's walls inwards)."""
    import open3d as o3d

    if len(points) == 0:
        return np.zeros((0, 3), np.float32)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
    n = np.asarray(pc.normals, np.float64)
    view = np.asarray(points, np.float64).mean(0) if viewpoint is None else np.asarray(viewpoint, np.float64)
    flip = ((view - points) * n).sum(1) < 0
    n[flip] *= -1
    return n.astype(np.float32)


def dense_crf(probs: np.ndarray, positions: np.ndarray, colors: np.ndarray, normals: np.ndarray,
              params: CrfParams) -> np.ndarray:
    """Mean-field posterior (N, K) float32 of a fully connected CRF with unaries ``-log probs`` (N, K) and the
    appearance and smoothness kernels over positions (N, 3) m, colours (N, 3) and unit normals (N, 3)."""
    import pydensecrf.densecrf as dcrf

    n, k = probs.shape
    if n == 0:
        return np.zeros((0, k), np.float32)
    crf = dcrf.DenseCRF(n, k)
    crf.setUnaryEnergy(np.ascontiguousarray(-np.log(np.clip(probs, 1e-8, 1.0)).T, np.float32))
    pos = np.asarray(positions, np.float64)
    pos = pos - pos.mean(0)
    appearance = np.concatenate([pos / params.appearance_position_std,
                                 np.asarray(colors, np.float64) / params.appearance_color_std], 1)
    smoothness = np.concatenate([pos / params.smoothness_position_std,
                                 np.asarray(normals, np.float64) / params.smoothness_normal_std], 1)
    if params.appearance_weight > 0:
        crf.addPairwiseEnergy(np.ascontiguousarray(appearance.T, np.float32), compat=params.appearance_weight)
    if params.smoothness_weight > 0:
        crf.addPairwiseEnergy(np.ascontiguousarray(smoothness.T, np.float32), compat=params.smoothness_weight)
    q = np.asarray(crf.inference(params.iterations), np.float32).T
    return np.ascontiguousarray(q)


def refine_map(m, params: CrfParams, *, viewpoint: np.ndarray | None = None, per_view: bool = True) -> CrfResult:
    """Run the CRF over the elements of map ``m`` that have class evidence and write the posterior back
    (``m.class_probs()`` / ``m.set_class_probs(probs, where=...)``, in ``m.cloud()`` order).

    ``per_view``: a map that sums every pixel's log-probabilities (the voxel grid and the point map with ``bayes`` /
    ``bayes-prior``) enters with them divided by its points per view (``m.class_probs_per_view()``), so that
    unaries weigh views, not pixels. Why: at 5 cm the grid's sum made 69-84 % of its voxels more certain than the
    pairwise terms can ever outweigh (unary gap at the 1e-8 clip, 18.4 nats, against weights 10 + 2) and the CRF
    added 0.5 pixel-MIoU points against the OctoMap's 4.7 (docs/EXPERIMENTS.md, "Issue 33's open gaps")."""
    t0 = time.perf_counter()
    cloud = m.cloud()
    has = cloud.labels != EMPTY_LABEL
    if m.label_set is None or not has.any():
        return CrfResult(0, 0, (time.perf_counter() - t0) * 1e3)
    check_crf(int(has.sum()), len(m.label_set), f"the {getattr(m.kind, 'value', 'map')} map")
    probs = m.class_probs_per_view() if per_view else m.class_probs()
    normals = cloud.normals
    if normals is None or not np.isfinite(normals).all():
        normals = estimate_normals(cloud.centers, 2.5 * max(cloud.resolution, 0.01), viewpoint)
    else:
        missing = np.linalg.norm(normals, axis=1) < 0.5
        if missing.any():
            normals = normals.copy()
            normals[missing] = estimate_normals(cloud.centers, 2.5 * max(cloud.resolution, 0.01),
                                                viewpoint)[missing]
    q = dense_crf(probs[has], cloud.centers[has], cloud.colors[has], normals[has], params)
    out = probs.copy()
    out[has] = q
    m.set_class_probs(out, where=has)
    changed = int((q.argmax(1) != probs[has].argmax(1)).sum())
    return CrfResult(int(has.sum()), changed, (time.perf_counter() - t0) * 1e3)
