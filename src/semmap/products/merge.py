"""Two maps of one place made one (``semmap merge A B --out C``): B is brought into A's frame by a given 4x4
transform or an estimated one, and every voxel both maps hold combines their evidence as the maps' own rules do.

- Alignment: ``T_A_B`` from a text file, or estimated from the occupied voxels: global registration (Open3D FPFH
  features with each voxel's class, RANSAC over all voxels and over the things alone) refined by ICP, beside the
  identity and ICP from it (maps of one SLAM session already share a frame); the candidate whose voxels most
  often meet a voxel of their class wins. An estimate is refused unless the share of the smaller map's occupied
  voxels with a partner within one voxel reaches ``min_overlap`` and their RMSE stays under 0.6 voxel (two maps
  of different places, or of too little common space).
- Resampling: B's voxels are looked up at the centres of A's lattice moved back by ``T_A_B`` (nearest voxel), so
  a rotated B leaves neither holes nor two voxels in one cell; the identity keeps B's keys as they are.
- Evidence: occupancy log-odds add and are clamped as OctoMap clamps them (the voxel grid's hit log-odds the same
  way, at its upper clamp); colours average by their observation counts; class states are folded together by the
  fusion rule's merge (``fusion.dispatch.merge_voxel``: a set fused as a measurement, log-odds and counts added and
  normalised), the rule inner nodes use. Maps of another kind, resolution, label set, fusion rule, occupancy model
  or state type are refused in one line.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError, FormatError, OutputError
from semmap.files.atomic import write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.fusion.half import from_half_bits, to_half_bits
from semmap.keys import KEY_LIMIT, coords_to_keys, index_in, keys_to_coords, pack_keys, unpack_keys
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MapKind
from semmap.maps.semantic_grid import CLAMP_MAX_LOGODDS, GridArrays
from semmap.maps.semantic_octomap import CellArrays, SemanticOctoMap
from semmap.products.occupancy import map_keys
from semmap.types import EMPTY_LABEL

#: The map kinds ``semmap merge`` combines (a TSDF's distances have no merge rule here).
MERGEABLE = (MapKind.OCTOMAP, MapKind.VOXELGRID, MapKind.POINTS)
#: Default least overlap of an estimated alignment: share of the smaller map's occupied voxels with a partner.
DEFAULT_MIN_OVERLAP = 0.3
#: Largest RMSE of the partners' distances of an estimated alignment, in voxels: aligned lattices give 0, a turned
#: lattice about 0.45 (cells meet off-centre), partners of a wrong fit spread over the whole voxel (about 0.77).
MAX_RMSE_VOXELS = 0.6
#: Partners are occupied voxels within this many voxels after alignment.
PARTNER_VOXELS = 1.0
#: Voxel keys and ``merge.json`` beside the merged map in an output folder.
SUMMARY = "merge.json"
TRANSFORM_FILE = "transform.txt"


@dataclass(frozen=True)
class Alignment:
    """``T_A_B`` (4x4, B's coordinates into A's frame), how it was found, and the overlap it gives."""

    transform: np.ndarray
    source: str  # "given" or "estimated"
    overlap: float  # share of the smaller map's occupied voxels with a partner in the other
    rmse_m: float  # RMSE of the partners' distances (m)
    start: str | None = None  # estimated: "global" (FPFH + RANSAC, then ICP) or "identity" (ICP alone)
    global_overlap: float | None = None  # the global registration's own overlap, before ICP

    def to_dict(self) -> dict:
        return {"transform": [[round(float(v), 9) for v in row] for row in self.transform], "source": self.source,
                "overlap": round(self.overlap, 4),
                "rmse_m": round(self.rmse_m, 5) if np.isfinite(self.rmse_m) else None, "start": self.start,
                "global_overlap": None if self.global_overlap is None else round(self.global_overlap, 4)}


# ---------------------------------------------------------------------------------------------- checks
def check_mergeable(a: SemanticMap, b: SemanticMap, names: tuple[str, str] = ("A", "B")) -> None:
    """One ConfigError line naming what differs when ``a`` and ``b`` cannot be merged."""
    for m, name in zip((a, b), names, strict=True):
        if m.kind not in MERGEABLE:
            raise ConfigError(f"{name}: a {m.kind.value} map cannot be merged; semmap merge combines "
                              f"{', '.join(k.value for k in MERGEABLE)} maps")
    differ = [
        ("map kind", a.kind.value, b.kind.value),
        ("resolution (m)", float(a.resolution), float(b.resolution)),
        ("label set", _names(a), _names(b)),
        ("fusion rule", a.fusion.to_dict(), b.fusion.to_dict()),
        ("occupancy model", _occupancy(a), _occupancy(b)),
        ("state type", getattr(getattr(a, "grid", None), "dtype", None), getattr(getattr(b, "grid", None), "dtype",
                                                                                 None)),
        ("free space", getattr(a, "free_space", None), getattr(b, "free_space", None)),
    ]
    for what, va, vb in differ:
        if va != vb:
            raise ConfigError(f"{names[0]} and {names[1]} differ in {what} ({_short(va)} and {_short(vb)}); only "
                              f"maps made with the same settings can be merged")


def _occupancy(m: SemanticMap) -> dict | None:
    params = getattr(m, "occupancy", None)
    return None if params is None else dict(vars(params))


def _names(m: SemanticMap) -> tuple[str, ...] | None:
    return None if m.label_set is None else tuple(m.label_set.names)


def _short(value: object) -> str:
    text = str(value)
    return text if len(text) <= 60 else text[:57] + "..."


def read_transform(path: str | Path) -> np.ndarray:
    """The 4x4 rigid transform in the text file ``path`` (4 rows of 4 numbers; ``#`` comments), or a FormatError."""
    from semmap.files.safe import read_text_limited

    rows = [line.split("#")[0].replace(",", " ").split() for line in read_text_limited(path, what="transform")
            .splitlines()]
    rows = [r for r in rows if r]
    try:
        values = [[float(v) for v in r] for r in rows]
    except ValueError:
        raise FormatError(f"{path}: a transform is 4 rows of 4 numbers") from None
    if [len(r) for r in values] != [4] * 4:
        raise FormatError(f"{path}: a transform is 4 rows of 4 finite numbers, got "
                          f"{' + '.join(str(len(r)) for r in rows) or 'no'} numbers in {len(rows)} rows")
    T = np.array(values, np.float64)
    if not np.isfinite(T).all():
        i, j = np.argwhere(~np.isfinite(T))[0]
        raise FormatError(f"{path}: a transform is 4 rows of 4 finite numbers; row {i + 1} holds {rows[i][j]!r}")
    R = T[:3, :3]
    if not (np.allclose(T[3], [0, 0, 0, 1], atol=1e-6) and np.allclose(R @ R.T, np.eye(3), atol=1e-4)
            and np.linalg.det(R) > 0):
        raise FormatError(f"{path}: not a rigid transform (rotation must be orthonormal with determinant +1, last "
                          f"row 0 0 0 1)")
    return T


# ---------------------------------------------------------------------------------------------- alignment
def occupied_centers(m: SemanticMap) -> tuple[np.ndarray, np.ndarray]:
    """World centres (N, 3) of the occupied voxels (a point map's points, voxelised) of any map, and their classes."""
    keys, labels, _ = map_keys(m)
    return keys_to_coords(keys, float(m.resolution)), labels


def overlap_of(src: np.ndarray, dst: np.ndarray, T: np.ndarray, resolution: float,
               partner: float = PARTNER_VOXELS) -> tuple[float, float]:
    """(share of the smaller cloud's points with a partner in the other within ``partner`` voxels, RMSE of their
    distances) of ``src`` moved by ``T`` against ``dst``; a fourth column (a class, far apart) must match too."""
    from scipy.spatial import cKDTree

    if len(src) == 0 or len(dst) == 0:
        return 0.0, float("nan")
    moved = src.copy()
    moved[:, :3] = src[:, :3] @ T[:3, :3].T + T[:3, 3]
    small, large = (moved, dst) if len(moved) <= len(dst) else (dst, moved)
    d, _ = cKDTree(large).query(small, distance_upper_bound=partner * resolution * 1.001)
    ok = np.isfinite(d)
    rmse = float(np.sqrt(np.mean(d[ok] ** 2))) if ok.any() else float("nan")
    return float(ok.mean()), rmse


def _with_classes(points: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Points with their class as a fourth coordinate, 1 km per class: only voxels of one class are partners."""
    return np.concatenate([points, 1000.0 * labels.astype(np.float64)[:, None]], axis=1)


def _cloud(points: np.ndarray, voxel: float, *, features: bool):
    """An Open3D cloud of ``points`` downsampled to ``voxel``, with normals (and FPFH features when asked)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    pc = pc.voxel_down_sample(voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
    fpfh = (reg.compute_fpfh_feature(pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=100))
            if features else None)
    return pc, fpfh


def _global(src, dst, src_f, dst_f, voxel: float, seed: int) -> np.ndarray:
    """FPFH + RANSAC: ``T`` taking ``src`` onto ``dst``."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # "too few correspondences" is no error
    result = reg.registration_ransac_based_on_feature_matching(
        src, dst, src_f, dst_f, True, 1.5 * voxel, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(100_000, 0.999))
    return np.asarray(result.transformation, np.float64)


def _icp(src, dst, init: np.ndarray, resolution: float) -> np.ndarray:
    """Point-to-plane ICP from ``init`` with correspondences within two voxels, then point-to-point within half a
    voxel, which settles aligned lattices on each other (voxel centres coincide)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    criteria = reg.ICPConvergenceCriteria(max_iteration=60)
    coarse = reg.registration_icp(src, dst, 2.0 * resolution, init, reg.TransformationEstimationPointToPlane(),
                                  criteria).transformation
    return np.asarray(reg.registration_icp(src, dst, 0.5 * resolution, coarse,
                                           reg.TransformationEstimationPointToPoint(), criteria).transformation)


#: RANSAC runs of the global registration per set of voxels (seeds 0, 1, ...): RANSAC ranks its hypotheses by
#: geometry alone, so a run may settle on a turned fit that the classes reject; a few runs give the right one too.
GLOBAL_TRIES = 4
#: Global results refined by ICP: the best by their class-aware overlap within two voxels.
GLOBAL_REFINED = 2
#: Weight of the one-hot class beside the FPFH histogram (values up to ~100): features match within a class.
CLASS_FEATURE_WEIGHT = 1000.0


def _with_class_features(pc, fpfh, points: np.ndarray, labels: np.ndarray, num_classes: int):
    """FPFH features of ``pc``'s points extended by the one-hot class of the nearest map voxel, so that RANSAC pairs
    only voxels of one class (a room's geometry alone often fits turned by 180 degrees, its classes do not)."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(points).query(np.asarray(pc.points))
    cls = np.where(labels[nearest] < num_classes, labels[nearest], 0).astype(np.int64)
    onehot = np.zeros((num_classes, len(cls)))
    onehot[cls, np.arange(len(cls))] = CLASS_FEATURE_WEIGHT
    out = o3d.pipelines.registration.Feature()
    out.data = np.vstack([np.asarray(fpfh.data), onehot])
    return out


def _global_subsets(label_set, la: np.ndarray, lb: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The voxels global registration looks at: all of them, and (when both maps hold enough) only the things,
    without walls, floor and ceiling, whose symmetry (a rectangular room fits itself turned by 180 degrees) the
    furniture breaks."""
    from semmap.labels import STUFF_CLASSES

    every = [(np.ones(len(la), bool), np.ones(len(lb), bool))]
    if label_set is None:
        return every
    stuff = np.array([i for i, n in enumerate(label_set.names) if n in STUFF_CLASSES or i == 0], np.int64)
    things = (~np.isin(la, stuff) & (la != EMPTY_LABEL), ~np.isin(lb, stuff) & (lb != EMPTY_LABEL))
    return every + ([things] if min(int(things[0].sum()), int(things[1].sum())) >= 50 else [])


def _global_of(pb: np.ndarray, lb: np.ndarray, pa: np.ndarray, la: np.ndarray, res: float, seed: int, label_set
               ) -> tuple[np.ndarray, float]:
    """One global registration (FPFH with classes, RANSAC) of B's voxels ``pb`` onto A's ``pa``, and its overlap."""
    k = len(label_set) if label_set is not None else 1
    voxel = max(2.0 * res, 0.05)  # features on a coarser cloud: FPFH needs neighbours, RANSAC fewer points
    src_g, src_f = _cloud(pb, voxel, features=True)
    dst_g, dst_f = _cloud(pa, voxel, features=True)
    src_f, dst_f = _with_class_features(src_g, src_f, pb, lb, k), _with_class_features(dst_g, dst_f, pa, la, k)
    g = _global(src_g, dst_g, src_f, dst_f, voxel, seed)
    return g, overlap_of(np.asarray(src_g.points), np.asarray(dst_g.points), g, voxel)[0]


def estimate_alignment(a: SemanticMap, b: SemanticMap, *, min_overlap: float = DEFAULT_MIN_OVERLAP,
                       seed: int = 0) -> Alignment:
    """``T_A_B`` from the occupied voxels (module docstring), refused in one line when the overlap is too small.
    Candidates (the identity, ICP from it, ICP from the best global registrations) are ranked by the share of
    voxels that meet a voxel of the same class within half a voxel (a shift by one voxel along a wall fits the
    geometry as well, not the classes); the first of equals wins."""
    res = float(a.resolution)
    (pa, la), (pb, lb) = occupied_centers(a), occupied_centers(b)
    if min(len(pa), len(pb)) < 10:
        raise ConfigError("a map has fewer than 10 occupied voxels: too little to align (give --transform)")
    src, _ = _cloud(pb, max(res, 0.02), features=False)
    dst, _ = _cloud(pa, max(res, 0.02), features=False)
    ca, cb = _with_classes(pa, la), _with_classes(pb, lb)
    rough = [_global_of(pb[ub], lb[ub], pa[ua], la[ua], res, seed + i, a.label_set)
             for ua, ub in _global_subsets(a.label_set, la, lb) for i in range(GLOBAL_TRIES)]
    rough.sort(key=lambda r: -overlap_of(cb, ca, r[0], res, 2.0)[0])
    candidates = [("identity", np.eye(4), None), ("identity", _icp(src, dst, np.eye(4), res), None),
                  *(("global", _icp(src, dst, g, res), g_overlap) for g, g_overlap in rough[:GLOBAL_REFINED])]
    best, best_score = None, -1.0
    for start, T, g_overlap in candidates:
        score = overlap_of(cb, ca, T, res, 0.5)[0]
        if score > best_score + 1e-9:
            best_score, best = score, Alignment(T, "estimated", *overlap_of(pb, pa, T, res), start, g_overlap)
    assert best is not None
    if not (best.overlap >= min_overlap and best.rmse_m <= MAX_RMSE_VOXELS * res):
        raise ConfigError(f"the maps do not overlap enough to be aligned: {100 * best.overlap:.1f} % of the smaller "
                          f"map's occupied voxels have a partner within a voxel (--min-overlap {min_overlap:g}), "
                          f"RMSE {best.rmse_m * 100:.1f} cm (at most {MAX_RMSE_VOXELS * res * 100:.1f} cm); "
                          f"give --transform if they are of one place")
    return best


# ---------------------------------------------------------------------------------------------- resampling
def resample(packed: np.ndarray, T: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """(target keys, sorted, packed; index into ``packed`` of the voxel each takes): B's voxels on A's lattice,
    each lattice cell taking the B voxel holding its centre moved back by ``T`` (nearest voxel)."""
    order = np.argsort(packed, kind="stable")
    src = packed[order]
    if np.array_equal(T, np.eye(4)):
        return src, order
    moved = keys_to_coords(unpack_keys(src), resolution) @ T[:3, :3].T + T[:3, 3]
    base = coords_to_keys(moved, resolution)
    offsets = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], np.int64)
    cand = (base[:, None, :] + offsets[None]).reshape(-1, 3)
    cand = np.unique(pack_keys(cand[np.all((cand >= 0) & (cand < KEY_LIMIT), axis=1)]))
    back = (keys_to_coords(unpack_keys(cand), resolution) - T[:3, 3]) @ T[:3, :3]
    keys = coords_to_keys(back, resolution)
    inside = np.all((keys >= 0) & (keys < KEY_LIMIT), axis=1)
    found = index_in(src, np.where(inside, pack_keys(keys), -1))
    ok = found >= 0
    return cand[ok], order[found[ok]]


# ---------------------------------------------------------------------------------------------- evidence
def _union(a_packed: np.ndarray, b_packed: np.ndarray, b_index: np.ndarray) -> tuple[np.ndarray, ...]:
    """(every key of either, its row in A or -1, its row in B or -1); ``b_packed`` sorted, ``b_index`` B's rows."""
    keys = np.union1d(a_packed, b_packed)
    ia = index_in(a_packed, keys)
    if not len(b_packed):  # nothing of B on A's lattice
        return keys, ia, np.full(len(keys), -1, np.int64)
    pos = index_in(b_packed, keys)
    return keys, ia, np.where(pos >= 0, b_index[np.maximum(pos, 0)], -1)


def _summed(va: np.ndarray, ia: np.ndarray, vb: np.ndarray, ib: np.ndarray, dtype) -> np.ndarray:
    """Per key, A's value plus B's (0 where a map lacks the key)."""
    out = np.zeros(len(ia), dtype)
    out[ia >= 0] += va[ia[ia >= 0]]
    out[ib >= 0] += vb[ib[ib >= 0]]
    return out


def _colours(rgb_a, cnt_a, ra, rgb_b, cnt_b, rb) -> tuple[np.ndarray, np.ndarray]:
    """Mean colours weighted by their observation counts, and the counts added (saturating at 65535)."""
    na = np.where(ra >= 0, cnt_a[np.maximum(ra, 0)], 0).astype(np.float64) if len(cnt_a) else np.zeros(len(ra))
    nb = np.where(rb >= 0, cnt_b[np.maximum(rb, 0)], 0).astype(np.float64) if len(cnt_b) else np.zeros(len(rb))
    ca = rgb_a[np.maximum(ra, 0)].astype(np.float64) if len(rgb_a) else np.zeros((len(ra), 3))
    cb = rgb_b[np.maximum(rb, 0)].astype(np.float64) if len(rgb_b) else np.zeros((len(rb), 3))
    n = na + nb
    mean = (ca * na[:, None] + cb * nb[:, None]) / np.where(n > 0, n, 1.0)[:, None]
    return np.floor(mean + 0.5).astype(np.uint8), np.minimum(n, 65535).astype(np.uint16)


def merged_states(fusion, num_classes: int, la: np.ndarray, va: np.ndarray, ra: np.ndarray, lb: np.ndarray,
                  vb: np.ndarray, rb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Class states (labels (n, S), float32 values (n, W)) of rows ``ra`` of A and ``rb`` of B (-1: none), folded
    together by the fusion rule where both hold one."""
    from semmap.products._merge_kernels import merge_states

    labels = np.full((len(ra), la.shape[1]), EMPTY_LABEL, np.uint16)
    values = np.zeros((len(ra), va.shape[1]), np.float32)
    for rows, lab, val in ((rb, lb, vb), (ra, la, va)):  # A's state where A has one, else B's
        has = rows >= 0
        labels[has], values[has] = lab[rows[has]], val[rows[has]]
    both = (ra >= 0) & (rb >= 0)
    if both.any() and values.shape[1]:
        entry = fusion.entry
        L, V = np.ascontiguousarray(labels[both]), np.ascontiguousarray(values[both])
        merge_states(L, V, np.ascontiguousarray(lb[rb[both]]), np.ascontiguousarray(vb[rb[both]], np.float32),
                     entry.code, entry.layout_code, entry.kernels()[0], fusion.kernel_params(num_classes))
        labels[both], values[both] = L, V
    return labels, values


def merge_cells(m: SemanticOctoMap, ca: CellArrays, cb: CellArrays, T: np.ndarray) -> CellArrays:
    """The OctoMap cells of ``ca`` and ``cb`` (B's moved by ``T``): log-odds added and clamped, colours averaged,
    class states folded by ``m``'s fusion rule."""
    b_keys, b_index = resample(cb.packed, T, m.resolution)
    keys, ia, ib = _union(ca.packed, b_keys, b_index)
    lo = np.clip(_summed(ca.logodds, ia, cb.logodds, ib, np.float32), m.occupancy.min_log, m.occupancy.max_log)
    ra = np.where(ia >= 0, ca.attr[np.maximum(ia, 0)], -1) if len(ca.attr) else np.full(len(keys), -1)
    rb = np.where(ib >= 0, cb.attr[np.maximum(ib, 0)], -1) if len(cb.attr) else np.full(len(keys), -1)
    has = (ra >= 0) | (rb >= 0)
    attr = np.full(len(keys), -1, np.int32)
    attr[has] = np.arange(int(has.sum()), dtype=np.int32)
    ra, rb = ra[has], rb[has]
    rgb, count = _colours(ca.rgb, ca.rgb_count, ra, cb.rgb, cb.rgb_count, rb)
    num_classes = len(m.label_set) if m.label_set is not None else 0
    labels, values = merged_states(m.fusion, num_classes, ca.sem_labels, ca.sem_probs, ra, cb.sem_labels,
                                   cb.sem_probs, rb)
    return CellArrays(keys, lo.astype(np.float32), attr, rgb, count, labels, values)


def merge_octomaps(a: SemanticOctoMap, b: SemanticOctoMap, T: np.ndarray) -> SemanticOctoMap:
    """One OctoMap of ``a`` and ``b`` (B's voxels moved by ``T_A_B``), with ``a``'s settings."""
    cells = merge_cells(a, a.cells(), b.cells(), T)
    return SemanticOctoMap.from_cells(a.resolution, cells, occupancy=a.occupancy, fusion=a.fusion,
                                      label_set=a.label_set, max_range=a.max_range, color_mode=a.color_mode,
                                      cell_evidence=a.cell_evidence)


def _grid_state(g, arrays: GridArrays) -> tuple[np.ndarray, np.ndarray]:
    """(labels, float32 values) of a grid's fusion state: the set pairs, or (no labels, the K numbers)."""
    values = arrays.dense if g.fusion.entry.dense else arrays.set_probs
    return arrays.set_labels, from_half_bits(values) if g.dtype == "float16" else values.astype(np.float32)


def merge_grid_arrays(g, a: GridArrays, b: GridArrays, T: np.ndarray) -> GridArrays:
    """The voxels of two semantic grids (B's moved by ``T``): hit log-odds added up to the clamp, hits added,
    colours and a point map's mean positions averaged, normals summed, class states folded by the rule."""
    b_keys, b_index = resample(b.packed, T, g.resolution)
    keys, ia, ib = _union(a.packed, b_keys, b_index)
    lo = np.minimum(_summed(a.logodds, ia, b.logodds, ib, np.float32), CLAMP_MAX_LOGODDS)
    hits_a = np.where(ia >= 0, a.hits[np.maximum(ia, 0)], 0).astype(np.float64) if len(ia) else np.zeros(0)
    hits_b = np.where(ib >= 0, b.hits[np.maximum(ib, 0)], 0).astype(np.float64) if len(ib) else np.zeros(0)
    rgb, count = _colours(a.rgb, a.rgb_count, ia, b.rgb, b.rgb_count, ib)
    la, va = _grid_state(g, a)
    lb, vb = _grid_state(g, b)
    labels, values = merged_states(g.fusion, g.num_classes, la, va, ia, lb, vb, ib)
    stored = to_half_bits(values) if g.dtype == "float16" else values
    empty = np.zeros((len(keys), 0), stored.dtype)
    dense, set_probs = (stored, empty) if g.fusion.entry.dense else (empty, stored)
    geo = a.positions.shape[1]
    positions = np.zeros((len(keys), geo), np.float32)
    normals = np.zeros((len(keys), geo), np.float32)
    if geo:
        pb = b.positions.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        n = np.maximum(hits_a + hits_b, 1.0)[:, None]
        positions[:] = (_picked(a.positions, ia) * hits_a[:, None] + _picked(pb, ib) * hits_b[:, None]) / n
        normals[:] = _picked(a.normal_sums, ia) + _picked(b.normal_sums @ T[:3, :3].T, ib)
    hits = np.minimum(hits_a + hits_b, 65535).astype(np.uint16)
    return GridArrays(keys, lo, rgb, count, hits, dense, labels, set_probs, positions, normals)


def _picked(values: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Rows ``rows`` of ``values`` (float64), zeros where a row is -1."""
    out = np.zeros((len(rows), values.shape[1]), np.float64)
    out[rows >= 0] = values[rows[rows >= 0]]
    return out


def merge_maps(a: SemanticMap, b: SemanticMap, T: np.ndarray | None = None) -> SemanticMap:
    """One map of ``a`` and ``b`` (B's voxels moved into A's frame by ``T_A_B``, default the identity)."""
    check_mergeable(a, b)
    T = np.eye(4) if T is None else np.asarray(T, np.float64)
    if a.kind == MapKind.OCTOMAP:
        return merge_octomaps(a, b, T)
    from semmap.maps.point_map import SemanticPointMap
    from semmap.maps.voxel_grid import SemanticVoxelGrid

    arrays = merge_grid_arrays(a.grid, a.grid.arrays(), b.grid.arrays(), T)
    if a.kind == MapKind.POINTS:
        out = SemanticPointMap(a.resolution, label_set=a.label_set, fusion=a.fusion, dtype=a.grid.dtype,
                               keyframes_only=a.keyframes_only)
        out.frames_integrated = a.frames_integrated + b.frames_integrated
    else:
        out = SemanticVoxelGrid(a.resolution, label_set=a.label_set, fusion=a.fusion, dtype=a.grid.dtype,
                                free_space=a.free_space, occupancy=a.occupancy, max_range=a.max_range)
        if a.geometry is not None:
            out.geometry = merge_octomaps(a.geometry, b.geometry, T)
    out.grid.load_arrays(arrays)
    return out


# ---------------------------------------------------------------------------------------------- semmap merge
def merge_map_files(a_path: Path, b_path: Path, out: Path, *, transform: Path | None = None,
                    min_overlap: float = DEFAULT_MIN_OVERLAP) -> dict:
    """``semmap merge``: the maps at ``a_path`` and ``b_path`` (``.semmap`` files or run folders) merged into
    ``out``: a ``.semmap`` file, or a folder of the map's files, ``transform.txt`` and ``merge.json``."""
    import time

    from semmap.limits import check
    from semmap.products.export import load_product_map

    check("probability", min_overlap, "--min-overlap")
    kind = OutputKind.FILE if Path(out).suffix == ".semmap" else OutputKind.FOLDER
    check_outputs([("--out", out, kind)], [("A", a_path), ("B", b_path), ("--transform", transform)])
    if kind == OutputKind.FOLDER and Path(out).is_dir() and any(Path(out).iterdir()) \
            and not (Path(out) / SUMMARY).is_file():
        raise OutputError(f"--out {out}: holds other files (not a merge of semmap); choose a new or empty folder "
                          f"(nothing was written)")
    a, a_file = load_product_map(Path(a_path))
    b, b_file = load_product_map(Path(b_path))
    check_mergeable(a, b, (str(a_file), str(b_file)))
    t0 = time.perf_counter()
    if transform is not None:
        T = read_transform(transform)
        check_in_key_range(b, T, transform)
        alignment = Alignment(T, "given", *overlap_of(occupied_centers(b)[0], occupied_centers(a)[0], T,
                                                      a.resolution))
        if alignment.overlap < min_overlap:
            raise ConfigError(f"--transform {transform}: it leaves {100 * alignment.overlap:.1f} % of the smaller "
                              f"map's occupied voxels with a partner within a voxel (--min-overlap {min_overlap:g}); "
                              f"check that it takes B's coordinates into A's frame, or give --min-overlap 0 to merge "
                              f"maps that share no space")
    else:
        alignment = estimate_alignment(a, b, min_overlap=min_overlap)
    t1 = time.perf_counter()
    merged = merge_maps(a, b, alignment.transform)
    summary = {"a": str(a_file), "b": str(b_file), "kind": a.kind.value, "resolution": float(a.resolution),
               "alignment": alignment.to_dict(), "occupied": {"a": _occupied(a), "b": _occupied(b),
                                                               "merged": _occupied(merged)},
               "seconds": {"alignment": round(t1 - t0, 3), "merge": round(time.perf_counter() - t1, 3)}}
    _write(merged, Path(out), kind, summary)
    return summary


def check_in_key_range(b: SemanticMap, T: np.ndarray, source: Path) -> None:
    """One ConfigError line when ``T`` moves any occupied voxel of ``b`` out of the space a map's keys address."""
    half = KEY_LIMIT / 2 * float(b.resolution)
    centers = occupied_centers(b)[0]
    moved = centers @ T[:3, :3].T + T[:3, 3]
    outside = int((np.abs(moved) >= 0.999 * half).any(axis=1).sum())
    if outside:
        raise ConfigError(f"--transform {source}: moves {outside:,} of B's {len(centers):,} occupied voxels out of the "
                          f"space a map at {float(b.resolution):g} m holds (|x|, |y|, |z| under {half:,.0f} m)")


def _occupied(m: SemanticMap) -> int:
    return len(map_keys(m)[0])


def _write(m: SemanticMap, out: Path, kind: OutputKind, summary: dict) -> None:
    """The merged map as one ``.semmap`` file, or a folder: its files, ``transform.txt``, ``merge.json``."""
    from semmap.io.map_files import save_map, save_map_files
    from semmap.io.staged_run import run_staged

    if kind == OutputKind.FILE:
        save_map(out, m)
        return

    def write(stage: Path) -> None:
        summary["files"] = save_map_files(m, stage)
        T = np.asarray(summary["alignment"]["transform"])
        write_text_atomic(stage / TRANSFORM_FILE, "\n".join(" ".join(f"{v:.9f}" for v in row) for row in T) + "\n")
        write_text_atomic(stage / SUMMARY, json.dumps(summary, indent=2) + "\n")

    run_staged(out, write)
