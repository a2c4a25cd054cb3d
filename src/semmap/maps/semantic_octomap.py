"""The semantic OctoMap: occupancy log-odds, free space, colour and fused class probabilities per voxel.

Leaves at the finest resolution live in a sharded hash table (see ``_hashtable``); inner nodes, pruning and
coarser resolutions are derived from them on demand (``coarsen``, ``maps.octree_tree``).  Occupancy follows
OctoMap exactly (float32 log-odds of hit 0.7 / miss 0.4, clamping 0.1192 / 0.971, occupied iff log-odds >= the
threshold's), and a scan is inserted like ``insertPointCloud(discretize=True)``, so the occupied / free /
unknown state of every cell matches the real OctoMap library's.  Class evidence is fused by any fusion rule
(:class:`~semmap.fusion.rules.FusionParams`, through ``fusion/dispatch.py``): a voxel keeps the rule's state, k
(label, confidence) pairs for ``topk`` (the paper's Algorithm 1), one pair for ``max``, K log-odds or counts for
the full-K rules.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

import numba as nb
import numpy as np

from semmap.errors import ConfigError
from semmap.fusion.rules import FusionParams
from semmap.keys import KEY_LIMIT, TREE_MAX_VAL, coords_to_keys, keys_to_coords, pack_keys, unpack_keys
from semmap.maps import _hashtable as ht
from semmap.maps import _octree_kernels as kern
from semmap.maps._cell_evidence import LABEL_RANGE, cell_mean_sets
from semmap.maps._cell_evidence import compile_variants as compile_mean_variants
from semmap.maps._coarsen import coarsen_cells
from semmap.maps._keys import EMPTY_KEY
from semmap.maps.base import MapState, check_state, restore_arrays
from semmap.maps.octree_tree import UNSET_COLOR, OctreeNodes, build_tree
from semmap.maps.registry import MapKind
from semmap.types import EMPTY_LABEL, LabelSet, MapCloud, Observation, TopKProbs, muted_grey

log = logging.getLogger("semmap")

UNKNOWN, FREE, OCCUPIED = 0, 1, 2
#: Largest temporary scan grid (cells = bytes); wider scans are range-limited with a warning.
GRID_CELL_LIMIT = 1 << 27
_INITIAL_SHARD_CAP = 8  # slots per shard of an empty map (8 KiB in all): the first scan sizes the table


class CellEvidence(str, Enum):
    """The class evidence a voxel takes from one scan: the mean of the distributions of all its points (``mean``,
    the default: it measured better at the same pixels, issue 33), or its first point's set (``first``: OctoMap's
    discretized insert, one point per cell)."""

    FIRST = "first"
    MEAN = "mean"


def logodds(p: float) -> np.float32:
    """OctoMap's float32 log-odds of a probability."""
    return np.float32(math.log(p / (1.0 - p)))


@dataclass(frozen=True)
class OccupancyParams:
    """OctoMap's sensor model: hit / miss probabilities, clamping bounds and the occupancy threshold."""

    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    occupancy_threshold: float = 0.5

    def __post_init__(self) -> None:
        for name in ("prob_hit", "prob_miss", "clamp_min", "clamp_max", "occupancy_threshold"):
            v = getattr(self, name)
            if not 0.0 < v < 1.0:
                raise ConfigError(f"{name} must be a probability in (0, 1), got {v}")
        if not self.prob_miss < 0.5 < self.prob_hit:
            raise ConfigError("need prob_miss < 0.5 < prob_hit")
        if not self.clamp_min < self.clamp_max:
            raise ConfigError("need clamp_min < clamp_max")

    @property
    def hit_log(self) -> np.float32:
        return logodds(self.prob_hit)

    @property
    def miss_log(self) -> np.float32:
        return logodds(self.prob_miss)

    @property
    def min_log(self) -> np.float32:
        return logodds(self.clamp_min)

    @property
    def max_log(self) -> np.float32:
        return logodds(self.clamp_max)

    @property
    def threshold_log(self) -> np.float32:
        return logodds(self.occupancy_threshold)


@dataclass
class InsertStats:
    """What one scan insertion did and how long each step took (milliseconds)."""

    points: int = 0
    endpoints: int = 0
    hits: int = 0
    free_cells: int = 0
    ray_steps: int = 0
    clear_rays: int = 0  #: rays of clear-only points (dynamic classes), one per end cell
    range_limited: bool = False
    ms: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class VoxelCloud:
    """Occupied (or any) voxels as flat arrays: keys, centres, log-odds, mean colour and top-k semantics (a full-K
    rule's k most probable classes)."""

    keys: np.ndarray  # (M, 3) int64 OctoMap keys
    centers: np.ndarray  # (M, 3) float64 metres
    logodds: np.ndarray  # (M,) float32
    colors: np.ndarray  # (M, 3) uint8 mean observed colour (grey where never coloured)
    labels: np.ndarray  # (M, k) uint16, EMPTY_LABEL where none
    probs: np.ndarray  # (M, k) float32

    def __len__(self) -> int:
        return int(self.keys.shape[0])


@dataclass(frozen=True)
class CellArrays:
    """Every stored finest-level cell, compacted: the raw state a file writer or a comparison needs."""

    packed: np.ndarray  # (M,) int64 packed keys
    logodds: np.ndarray  # (M,) float32
    attr: np.ndarray  # (M,) int32 row into the attribute arrays, -1 = none
    rgb: np.ndarray  # (A, 3) uint8 running mean of the observed colours
    rgb_count: np.ndarray  # (A,) uint16 colour observations (saturates; then a slow moving average)
    sem_labels: np.ndarray  # (A, S) uint16 the fusion rule's labels (S = k pairs for topk, 0 for full-K rules)
    sem_probs: np.ndarray  # (A, W) float32 its values (confidences, or K log-odds / counts)


@dataclass
class _ScanScratch:
    """Per-point work arrays of one insertion, kept by the map and reused while big enough."""

    keys: np.ndarray  # (n, 3) int32 keys of the points
    valid: np.ndarray  # (n,) bool
    first: np.ndarray  # (n,) int64 first point of each endpoint cell
    packed: np.ndarray  # (n,) int64 packed key of each endpoint cell
    targets: np.ndarray  # (n, 3) float32 ray target of each endpoint cell
    hit: np.ndarray  # (n,) bool endpoint cell is a hit (not a max-range reading)
    rows: np.ndarray  # (n,) int64 attribute row of each endpoint cell
    free: np.ndarray = field(default_factory=lambda: np.empty(1 << 16, np.int64))  # packed free cells (grows)

    @classmethod
    def empty(cls, n: int = 0) -> _ScanScratch:
        return cls(np.empty((n, 3), np.int32), np.empty(n, np.bool_), np.empty(n, np.int64), np.empty(n, np.int64),
                   np.empty((n, 3), np.float32), np.empty(n, np.bool_), np.empty(n, np.int64))

    @property
    def capacity(self) -> int:
        return int(self.valid.shape[0])


class SemanticOctoMap:
    """Probabilistic 3D occupancy map with colour and fused semantics per voxel, OctoMap-compatible keys.

    Implements :class:`semmap.maps.base.SemanticMap` (``integrate``, ``cloud``, ``describe``);
    ``fusion`` is the label-fusion rule and its settings (default ``topk``, k = 3: the paper's map);
    ``color_mode`` is the voxel colour its ``.ot`` file shows (``class`` or ``rgb``); ``cell_evidence`` is the
    class evidence a voxel takes from a scan (:class:`CellEvidence`; occupancy is OctoMap's either way).
    """

    kind = MapKind.OCTOMAP
    needs_normals = False

    def __init__(self, resolution: float = 0.05, *, occupancy: OccupancyParams | None = None,
                 fusion: FusionParams | None = None, label_set: LabelSet | None = None,
                 max_range: float = -1.0, grid_cell_limit: int = GRID_CELL_LIMIT, color_mode: str = "class",
                 cell_evidence: CellEvidence | str = CellEvidence.MEAN, decay: float = 0.0) -> None:
        if not (math.isfinite(resolution) and 0.001 <= resolution <= 10.0):
            raise ConfigError(f"resolution must be between 0.001 and 10 m, got {resolution}")
        if not (math.isfinite(decay) and 0.0 <= decay < 1.0):
            raise ConfigError(f"--decay must be in [0, 1) (log-odds lost per frame unseen), got {decay}")
        self.decay = float(decay)  # cells a scan does not observe lose this share of their log-odds (0: OctoMap)
        self.resolution = float(resolution)
        self.occupancy = occupancy or OccupancyParams()
        self.fusion = fusion or FusionParams()
        self.label_set = label_set
        self._num_classes = len(label_set) if label_set is not None else 0
        if self._entry.dense and label_set is None:
            raise ConfigError(f"the {self._entry.name} fusion rule keeps K values per voxel: give the map a label set")
        self._params = self.fusion.kernel_params(self._num_classes)
        self._widths = self._entry.widths(self.fusion, self._num_classes)
        self.max_range = float(max_range)
        self.grid_cell_limit = int(grid_cell_limit)
        self.color_mode = color_mode
        try:
            self.cell_evidence = CellEvidence(cell_evidence)
        except ValueError:
            raise ConfigError(f"cell evidence must be one of {[e.value for e in CellEvidence]}, "
                              f"got {cell_evidence!r}") from None
        self._tree_counts: dict[str, int] | None = None
        self._hit, self._miss = self.occupancy.hit_log, self.occupancy.miss_log
        self._min, self._max = self.occupancy.min_log, self.occupancy.max_log
        self._thr = self.occupancy.threshold_log
        self._alloc_table(_INITIAL_SHARD_CAP)
        self._alloc_attributes(256)
        self._n_attr = 0
        self._grid = np.zeros(0, np.uint8)
        self._scratch = _ScanScratch.empty()
        self._warned_range = False

    @property
    def _entry(self):
        """The fusion rule's registry entry (looked up, not held: a checkpoint saves the map's plain state)."""
        return self.fusion.entry

    # ------------------------------------------------------------------ storage
    def _alloc_table(self, shard_cap: int) -> None:
        n = ht.N_SHARDS * shard_cap
        self._shard_cap = shard_cap
        self._keys = np.full(n, EMPTY_KEY, np.int64)
        self._logodds = np.zeros(n, np.float32)
        self._attr = np.full(n, -1, np.int32)
        self._counts = np.zeros(ht.N_SHARDS, np.int64)

    def _alloc_attributes(self, rows: int) -> None:
        s, w = self._widths
        self._rgb = np.zeros((rows, 3), np.uint8)
        self._rgb_count = np.zeros(rows, np.uint16)
        self._sem_labels = np.full((rows, s), EMPTY_LABEL, np.uint16)
        self._sem_probs = np.zeros((rows, w), np.float32)

    def _grow_table(self, min_cap: int) -> None:
        """Rehash into shards of at least ``min_cap`` slots and the growth factor (more if a lane overflows)."""
        cap = ht.next_capacity(self._shard_cap, min_cap)
        old = (self._keys, self._logodds, self._attr, self._shard_cap)
        while True:
            self._alloc_table(cap)
            if ht.rehash(old[0], old[1], old[2], old[3], self._keys, self._logodds, self._attr, cap, self._counts):
                return
            cap = ht.round_capacity(cap * ht.GROWTH)  # a lane overflowed (very uneven keys): bigger still

    def _grow_for(self, pending: int) -> None:
        """Grow mid-frame by the usual factor, or at once far enough for ``pending`` more cells (all counted as
        new; a shard gets its share and up to three standard deviations more, the 8 cells of a z-group hashing
        together) at ``SIZED_LOAD``, so that a frame rarely grows the table twice.  (The fullest shard's share is
        not estimated from the counts so far: a few cells in a new map would make it look twice the mean.)"""
        share = pending / ht.N_SHARDS
        spread = 3.0 * math.sqrt(ht.GROUP * share)
        self._grow_table((self._counts.max() + share + spread) / ht.SIZED_LOAD)

    def _fill_limit(self) -> int:
        """Entries a shard may hold before it must grow (keeps linear probing short)."""
        return int(ht.HARD_LOAD * self._shard_cap)

    def _ensure_attributes(self, rows: int) -> None:
        have = self._rgb_count.shape[0]
        if rows <= have:
            return
        new = max(rows, int(have * ht.GROWTH))
        old = (self._rgb, self._rgb_count, self._sem_labels, self._sem_probs)
        self._alloc_attributes(new)
        n = self._n_attr
        self._rgb[:n], self._rgb_count[:n] = old[0][:n], old[1][:n]
        self._sem_labels[:n], self._sem_probs[:n] = old[2][:n], old[3][:n]

    def _point_buffers(self, n: int) -> _ScanScratch:
        """Per-point scratch reused between scans (no page faults on every frame)."""
        if self._scratch.capacity < n:
            free = self._scratch.free  # sized by the scans seen so far, not by their points
            self._scratch = _ScanScratch.empty(int(n * 1.25) + 16)
            self._scratch.free = free
        return self._scratch

    def _grid_buffer(self, cells: int) -> np.ndarray:
        if self._grid.shape[0] < cells:
            self._grid = np.zeros(int(cells * 1.25) + 64, np.uint8)
        return self._grid

    # ------------------------------------------------------------------ insertion
    def insert_points(self, points: np.ndarray, origin: np.ndarray, *, colors: np.ndarray | None = None,
                      semantics: TopKProbs | None = None, clear: np.ndarray | None = None) -> InsertStats:
        """Insert one scan: world points (N, 3) seen from sensor ``origin`` (3,), optional colours (N, 3)
        uint8 and per-point top-k class distributions (N, k).  Points are used as float32, like OctoMap.
        ``clear`` (M, 3) are clear-only points (dynamic classes): their rays mark free cells as the others' do,
        but their end cells get no hit, colour or class (without them the insertion is OctoMap's exactly)."""
        t0 = time.perf_counter()
        pts, org, col, sem_l, sem_p = self._validated(points, origin, colors, semantics)
        stats, n = InsertStats(points=len(pts)), len(pts)
        if clear is not None and len(clear):
            pts = np.concatenate([pts, self._validated(clear, origin, None, None)[0].astype(pts.dtype)])
        if len(pts) == 0:
            return stats
        res, rf = self.resolution, 1.0 / self.resolution
        threads = nb.get_num_threads()

        # 1. keys and bounding box (of the clear-only points too); the scan grid around them
        buf = self._point_buffers(len(pts))
        keys, valid = buf.keys[: len(pts)], buf.valid[: len(pts)]
        boxes = kern.point_keys(pts, rf, threads, keys, valid)
        lo, hi = boxes[:, :3].min(axis=0), boxes[:, 3:].max(axis=0)
        if (hi < lo).any():
            return stats
        okey = coords_to_keys(org[None], res)[0]
        origin_ok = bool(((okey >= 0) & (okey < KEY_LIMIT)).all())
        lo, hi, max_range = self._scan_box(lo, hi, okey, origin_ok, org, stats)
        (gnx, gny, gnz), (g0x, g0y, g0z) = (int(v) for v in hi - lo + 1), (int(v) for v in lo)
        n_cells = gnx * gny * gnz
        grid = self._grid_buffer(n_cells)
        t1 = time.perf_counter()
        stats.ms["keys"] = (t1 - t0) * 1e3

        try:  # the scratch grid must come back all-zero even if something below fails
            # 2. voxel filter and ray targets: the first point of each endpoint cell represents it
            m = kern.scan_endpoints(keys[:n], valid[:n], grid, g0x, g0y, g0z, gnx, gny, gnz, org, res, max_range,
                                    buf.first, buf.packed, buf.targets, buf.hit)
            first, packed, targets, hit = buf.first[:m], buf.packed[:m], buf.targets[:m], buf.hit[:m]
            targets = self._more_targets(targets, keys, valid, n, (lo, hi), org, max_range, stats)
            t2 = time.perf_counter()
            stats.ms["voxel_filter"] = (t2 - t1) * 1e3

            # 3. rays to every endpoint cell centre (or to the max-range point) mark free cells
            if origin_ok:
                stats.ray_steps = kern.cast_rays(org, targets, res, rf, grid, g0x, g0y, g0z, gny, gnz, threads)
            t3 = time.perf_counter()
            stats.ms["raycast"] = (t3 - t2) * 1e3

            # 4. free cells in grid order (resets the grid)
            buf.free, n_free = kern.collect_free(grid, n_cells, g0x, g0y, g0z, gny, gnz, buf.free)
        except BaseException:
            grid[:n_cells] = 0
            raise
        stats.endpoints, stats.hits, stats.free_cells = m, int(np.count_nonzero(hit)), n_free
        t4 = time.perf_counter()
        stats.ms["collect"] = (t4 - t3) * 1e3

        # 5. occupancy log-odds (misses, then hits), attribute rows of first hits; unseen cells decay (--decay)
        slots = self._update_occupancy(buf.free, n_free, packed, hit, threads)
        self._ensure_attributes(self._n_attr + int(np.count_nonzero(self._attr[slots[hit]] < 0)))  # first hits
        rows = buf.rows[:m]
        self._n_attr = kern.assign_rows(self._attr, slots, hit, self._n_attr, rows)
        t5 = time.perf_counter()
        stats.ms["occupancy"] = (t5 - t4) * 1e3

        # 5. colour and semantics of the hit cells
        if col is not None or sem_l is not None:
            k = self.fusion.k
            update, finish = self._entry.kernels()
            if sem_l is not None and self.cell_evidence == CellEvidence.MEAN:  # one measurement per cell
                sem_l, sem_p = self._cell_means(keys[:n], valid[:n], packed, first, sem_l, sem_p, threads)
                col = None if col is None else np.ascontiguousarray(col[first])
                first = np.arange(m, dtype=np.int64)
            kern.update_attributes(rows, first,
                                   col if col is not None else np.zeros((1, 3), np.uint8), col is not None,
                                   sem_l if sem_l is not None else np.zeros((1, k), np.uint16),
                                   sem_p if sem_p is not None else np.zeros((1, k), np.float32), sem_l is not None,
                                   self._rgb, self._rgb_count, self._sem_labels, self._sem_probs,
                                   self._entry.code, update, finish, self._params, threads)
        stats.ms["attributes"] = (time.perf_counter() - t5) * 1e3
        return stats

    def _cell_means(self, keys: np.ndarray, valid: np.ndarray, packed: np.ndarray, first: np.ndarray,
                    sem_l: np.ndarray, sem_p: np.ndarray, threads: int) -> tuple[np.ndarray, np.ndarray]:
        """Per endpoint cell, the mean class distribution of all its points as a top-k set (``CellEvidence.MEAN``);
        without a label set, every class id counts."""
        return cell_mean_sets(keys, valid, packed, first, sem_l, sem_p, self._num_classes or LABEL_RANGE,
                              int(EMPTY_LABEL), threads)

    def _more_targets(self, targets: np.ndarray, keys: np.ndarray, valid: np.ndarray, n: int,
                      box: tuple[np.ndarray, np.ndarray], org: np.ndarray, max_range: float,
                      stats: InsertStats) -> np.ndarray:
        """The ray targets beside the grid's endpoint cells: max-range readings beyond the range-limited grid,
        and one target per cell of the clear-only points (``keys[n:]``): its centre, or the max-range point."""
        more = []
        outside = self._far_endpoints(keys[:n], valid[:n], *box) if max_range >= 0 else None
        if outside is not None and outside.size:
            more.append(kern.far_targets(keys, outside, org, self.resolution, max_range))
        if keys.shape[0] > n:
            ok = np.flatnonzero(valid[n:])
            _, first = np.unique(pack_keys(keys[n:][ok]), return_index=True)
            stats.clear_rays = int(first.size)
            more.append(kern.far_targets(keys, np.sort(ok[first]) + n, org, self.resolution, max_range))
        return np.concatenate([targets, *more]) if more else targets

    def _validated(self, points, origin, colors, semantics):
        """Inputs as contiguous arrays of the kernels' dtypes, or a ConfigError saying what is wrong."""
        pts = np.asarray(points)
        pts = np.ascontiguousarray(pts, dtype=pts.dtype if pts.dtype in (np.float32, np.float64) else np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ConfigError(f"points must be (N, 3), got {pts.shape}")
        org = np.asarray(origin, dtype=np.float32).reshape(-1)
        if org.shape != (3,) or not np.isfinite(org).all():
            raise ConfigError(f"sensor origin must be 3 finite numbers, got {origin!r}")
        n = pts.shape[0]
        col = None
        if colors is not None:
            col = np.ascontiguousarray(colors, dtype=np.uint8)
            if col.shape != (n, 3):
                raise ConfigError(f"colours must be ({n}, 3), got {col.shape}")
        sem_l = sem_p = None
        if semantics is not None:
            sem_l = np.ascontiguousarray(semantics.labels, dtype=np.uint16)
            sem_p = np.ascontiguousarray(semantics.probs, dtype=np.float32)
            if self._entry.sets_of_k and sem_l.shape != (n, self.fusion.k):
                raise ConfigError(f"semantics must be ({n}, {self.fusion.k}), got {sem_l.shape}")
            if sem_l.ndim != 2 or sem_l.shape[0] != n or sem_l.shape[1] == 0 or sem_p.shape != sem_l.shape:
                raise ConfigError(f"semantics must be ({n}, k) labels and probabilities, got {sem_l.shape} and "
                                  f"{sem_p.shape}")
            if self.label_set is not None:
                top = kern.max_class_id(sem_l, int(EMPTY_LABEL))
                if top >= len(self.label_set):
                    raise ConfigError(f"class id {top} is outside the map's label set "
                                      f"({len(self.label_set)} classes)")
        return pts, org, col, sem_l, sem_p

    def _scan_box(self, lo: np.ndarray, hi: np.ndarray, okey: np.ndarray, origin_ok: bool, org: np.ndarray,
                  stats: InsertStats) -> tuple[np.ndarray, np.ndarray, float]:
        """Key box of the temporary scan grid (endpoints, origin, one-cell margin, z padded to 8) and the
        max range in force: the map's own, or a tighter one when the scan would need too big a grid."""
        if origin_ok:
            lo, hi = np.minimum(lo, okey), np.maximum(hi, okey)
        max_range = self.max_range
        lo, hi = self._clip_box(lo, hi, okey, max_range, origin_ok)
        if int(np.prod(hi - lo + 1)) > self.grid_cell_limit and origin_ok:
            limit = self._range_cut()
            max_range = limit if max_range < 0 else min(max_range, limit)
            stats.range_limited = True
            if not self._warned_range:
                log.warning("--resolution %g m is too fine for the range of the scans: ray-casting one would take more "
                            "than %d cells, so readings beyond %.2f m are cut off (choose a coarser --resolution, or "
                            "--max-range to set the cut)", self.resolution, self.grid_cell_limit, max_range)
                self._warned_range = True
            lo, hi = self._clip_box(lo, hi, okey, max_range, origin_ok)
        if int(np.prod(hi - lo + 1)) > self.grid_cell_limit:
            raise ConfigError(f"scan spans {(hi - lo + 1).tolist()} voxels and its sensor origin {org.tolist()} "
                              "is outside the map's key range")
        pad = (-int(hi[2] - lo[2] + 1)) % 8  # the free-cell scan reads the grid 8 bytes at a time
        if hi[2] + pad < KEY_LIMIT:
            hi[2] += pad
        else:
            lo[2] -= pad
        return lo, hi, max_range

    def _update_occupancy(self, free: np.ndarray, n_free: int, packed: np.ndarray, hit: np.ndarray,
                          threads: int) -> np.ndarray:
        """Miss updates of the free cells, hit updates of the endpoint cells (a shard that fills up pauses, the
        table grows, the update resumes); returns the slot of every endpoint cell (stale for max-range ones)."""
        no_slots = np.zeros(0, np.int64)
        hits = packed[hit] if not hit.all() else packed
        self._update_cells(free, n_free, self._miss, no_slots, threads, more=hits.shape[0])
        slots = np.empty(hits.shape[0], np.int64)
        grown = self._update_cells(hits, hits.shape[0], self._hit, slots, threads)
        if self._counts.max() > ht.MAX_LOAD * self._shard_cap:
            self._grow_table(ht.round_capacity(self._shard_cap * ht.GROWTH))
            grown = True
        if grown:  # slots recorded before the table moved are stale
            slots = ht.lookup_many(self._keys, self._shard_cap, hits)
        if self.decay > 0.0:
            self._decay_unseen(free[:n_free], slots)
        if hits is packed:
            return slots
        out = np.zeros(packed.shape[0], np.int64)
        out[hit] = slots
        return out

    def _decay_unseen(self, free: np.ndarray, hit_slots: np.ndarray) -> None:
        """``decay``: the log-odds of every cell this scan neither hit nor crossed move towards 0 (unknown) by that
        share, so that old evidence gives way sooner to what later scans see."""
        seen = np.concatenate([ht.lookup_many(self._keys, self._shard_cap, free), hit_slots])
        kern.decay_unseen(self._keys, self._logodds, seen, np.float32(1.0 - self.decay))

    def _update_cells(self, cells: np.ndarray, n: int, delta: np.float32, slots: np.ndarray, threads: int, *,
                      more: int = 0) -> bool:
        """Add ``delta`` to the log-odds of ``cells[:n]``, clamped, growing the table as shards fill (for ``more``
        cells of this scan still to come as well, as many of them new as of the cells so far); returns whether it
        grew."""
        progress = np.zeros(max(1, threads), np.int64)
        before, grown = int(self._counts.sum()), False
        while not kern.update_cells(cells, n, progress, self._keys, self._logodds, self._attr, self._counts,
                                    self._shard_cap, delta, self._min, self._max, self._fill_limit(), slots):
            # each part looks at every cell and updates its own shards': the mean progress is the cells done
            new_share = min((int(self._counts.sum()) - before) / max(float(progress.mean()), 1.0), 1.0)
            self._grow_for(int(new_share * (int((n - progress).max()) + more)))
            grown = True
        return grown

    def _clip_box(self, lo: np.ndarray, hi: np.ndarray, okey: np.ndarray, max_range: float,
                  origin_ok: bool) -> tuple[np.ndarray, np.ndarray]:
        """Scan grid box: the keys' box with a one-cell margin, cut to the max-range ball around the origin."""
        lo = np.maximum(lo - 1, 0)
        hi = np.minimum(hi + 1, KEY_LIMIT - 1)
        if max_range >= 0 and origin_ok:
            r = math.ceil(max_range / self.resolution) + 2
            lo = np.maximum(lo, okey - r)
            hi = np.minimum(hi, okey + r)
        return lo, hi

    @staticmethod
    def _far_endpoints(keys: np.ndarray, valid: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """First point of each endpoint cell outside the range-limited grid (all of them max-range readings)."""
        out = valid & ((keys < lo).any(axis=1) | (keys > hi).any(axis=1))
        idx = np.flatnonzero(out)
        if idx.size == 0:
            return idx
        _, first = np.unique(pack_keys(keys[idx]), return_index=True)
        return np.sort(idx[first])

    # ------------------------------------------------------------------ queries
    @property
    def num_leaves(self) -> int:
        """Number of finest-level cells known (occupied or free)."""
        return int(self._counts.sum())

    def _used(self) -> np.ndarray:
        return self._keys != EMPTY_KEY

    @property
    def num_occupied(self) -> int:
        return int(((self._logodds >= self._thr) & self._used()).sum())

    @property
    def num_free(self) -> int:
        return self.num_leaves - self.num_occupied

    # ------------------------------------------------------------------ checkpoints
    #: Checkpoint schema: stable name -> attribute holding it (tests check that it covers every array the map holds).
    STATE_ARRAYS: ClassVar[dict[str, str]] = {
        "table_keys": "_keys", "table_logodds": "_logodds", "table_rows": "_attr", "shard_counts": "_counts",
        "rgb": "_rgb", "rgb_count": "_rgb_count", "class_labels": "_sem_labels", "class_values": "_sem_probs"}

    def state(self) -> MapState:
        """Everything integration changes, by the checkpoint schema's names (layout and slack included, so that a
        resumed run ends byte for byte and byte count as an uninterrupted one)."""
        out = {name: getattr(self, attr) for name, attr in self.STATE_ARRAYS.items()}
        return {**out, "shard_capacity": np.int64(self._shard_cap), "rows_used": np.int64(self._n_attr),
                "warned_range": np.bool_(self._warned_range)}

    def restore(self, state: MapState) -> None:
        """Continue from :meth:`state` of a map built with the same parameters."""
        check_state(state, (*self.STATE_ARRAYS, "shard_capacity", "rows_used", "warned_range"), "the OctoMap")
        restore_arrays(self, self.STATE_ARRAYS, state, "the OctoMap", "map")
        self._shard_cap, self._n_attr = int(state["shard_capacity"]), int(state["rows_used"])
        self._warned_range = bool(state["warned_range"])
        self._tree_counts = None

    def _range_cut(self) -> float:
        """The range (m) a scan is cut to when its ray-casting grid would pass ``grid_cell_limit`` cells."""
        return (int(self.grid_cell_limit ** (1.0 / 3.0)) - 6) / 2 * self.resolution

    @property
    def range_cut_m(self) -> float | None:
        """The range scans were cut to because the resolution is too fine for them (None: never cut)."""
        return self._range_cut() if self._warned_range else None

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the map: hash table (with its slack) and attribute arrays (not the scan scratch grid)."""
        arrays = (self._keys, self._logodds, self._attr, self._counts, self._rgb, self._rgb_count,
                  self._sem_labels, self._sem_probs, self._params)
        return int(sum(a.nbytes for a in arrays))

    def _slots_of(self, points: np.ndarray) -> np.ndarray:
        return ht.slots_at(self._keys, self._shard_cap, points, self.resolution)

    def state_at(self, points: np.ndarray) -> np.ndarray:
        """Cell state (UNKNOWN 0, FREE 1, OCCUPIED 2) at each (N, 3) world point."""
        slots = self._slots_of(points)
        out = np.full(slots.shape[0], UNKNOWN, np.int8)
        known = slots >= 0
        out[known] = np.where(self._logodds[slots[known]] >= self._thr, OCCUPIED, FREE)
        return out

    def semantics_at(self, points: np.ndarray) -> TopKProbs:
        """Fused top-k class distribution at each (N, 3) point (empty sets where nothing was observed)."""
        slots = self._slots_of(points)
        known = slots >= 0
        rows = np.full(slots.shape[0], -1, np.int64)
        rows[known] = self._attr[slots[known]]
        labels, values = self._states(rows, self._sem_labels, self._sem_probs)
        return self._entry.sets(labels, values, self._num_classes, self.fusion.k)

    def _states(self, rows: np.ndarray, sem_labels: np.ndarray, sem_probs: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """The fusion state (labels, values) of attribute rows ``rows``; rows -1 get an empty state."""
        labels = np.full((rows.shape[0], sem_labels.shape[1]), EMPTY_LABEL, np.uint16)
        values = np.zeros((rows.shape[0], sem_probs.shape[1]), np.float32)
        has = rows >= 0
        labels[has] = sem_labels[rows[has]]
        values[has] = sem_probs[rows[has]]
        return labels, values

    def class_at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Most probable class and its probability at each (N, 3) world point where the map is occupied, as
        :meth:`cloud` reports them; EMPTY_LABEL and 0 at free or unknown points."""
        sem, occupied = self.semantics_at(points), self.state_at(points) == OCCUPIED
        return (np.where(occupied, sem.labels[:, 0], EMPTY_LABEL).astype(np.uint16),
                np.where(occupied, sem.probs[:, 0], 0.0).astype(np.float32))

    def cells(self) -> CellArrays:
        """All stored cells, compacted, sorted by packed key (deterministic order)."""
        used = np.flatnonzero(self._used())
        order = np.argsort(self._keys[used], kind="stable")
        used = used[order]
        n = self._n_attr
        return CellArrays(self._keys[used].copy(), self._logodds[used].copy(), self._attr[used].copy(),
                          self._rgb[:n].copy(), self._rgb_count[:n].copy(),
                          self._sem_labels[:n].copy(), self._sem_probs[:n].copy())

    def voxels(self, *, occupied_only: bool = True) -> VoxelCloud:
        """Voxels as flat arrays (occupied ones by default), sorted by key."""
        used = np.flatnonzero(self._used())
        if occupied_only:  # select before sorting: the free cells are most of the tree
            used = used[self._logodds[used] >= self._thr]
        used = used[np.argsort(self._keys[used], kind="stable")]
        keys = unpack_keys(self._keys[used])
        rows = self._attr[used]
        colors = np.full((keys.shape[0], 3), 128, np.uint8)
        has = rows >= 0
        cnt = self._rgb_count[rows[has]]
        colored = np.flatnonzero(has)[cnt > 0]
        colors[colored] = self._rgb[rows[colored]]
        sets = self._entry.sets(*self._states(rows, self._sem_labels, self._sem_probs), self._num_classes,
                                self.fusion.k)
        return VoxelCloud(keys, keys_to_coords(keys, self.resolution), self._logodds[used], colors, sets.labels,
                          sets.probs)

    def is_occupied(self, logodds_values: np.ndarray) -> np.ndarray:
        return np.asarray(logodds_values) >= self._thr

    def leaf_colors(self, cells: CellArrays, *, color_mode: str = "class") -> np.ndarray:
        """Colour each cell shows in an OctoMap file: free cells unset (white); occupied cells their mean
        observed colour (``rgb``) or, in ``class`` mode with a label set, their top class colour when that is
        a real class, else (0 = unknown / void / background, or no semantics) their observed colour in grey."""
        if color_mode not in ("class", "rgb"):
            raise ConfigError(f"color mode must be 'class' or 'rgb', got {color_mode!r}")
        n = cells.packed.shape[0]
        out = np.full((n, 3), UNSET_COLOR, np.uint8)
        occ = np.flatnonzero(cells.logodds >= self._thr)
        out[occ] = 128
        rows = cells.attr[occ]
        has = rows >= 0
        occ, rows = occ[has], rows[has]
        cnt = cells.rgb_count[rows]
        colored = cnt > 0
        mean = cells.rgb[rows[colored]].copy()
        mean[np.all(mean == UNSET_COLOR, axis=1)] = UNSET_COLOR - 1
        out[occ[colored]] = mean
        if color_mode == "class" and self.label_set is not None:
            top = self._entry.top(cells.sem_labels[rows], cells.sem_probs[rows], self._num_classes)[0]
            labelled = (top < len(self.label_set)) & (top != 0)
            out[occ[colored]] = muted_grey(mean)
            out[occ[labelled]] = self.label_set.colors[top[labelled]]
        return out

    def tree(self, *, color_mode: str = "class") -> OctreeNodes:
        """The pruned octree (inner nodes: max occupancy, mean colour) in OctoMap serialisation order.
        Children are pruned only when they agree in occupancy, written colour, top class and its confidence."""
        c = self.cells()
        colors = self.leaf_colors(c, color_mode=color_mode)
        labels = np.full(c.packed.shape[0], EMPTY_LABEL, np.uint16)
        confs = np.zeros(c.packed.shape[0], np.float32)
        occ = np.flatnonzero((c.logodds >= self._thr) & (c.attr >= 0))
        labels[occ], confs[occ] = self._entry.top(c.sem_labels[c.attr[occ]], c.sem_probs[c.attr[occ]],
                                                  self._num_classes)
        return build_tree(unpack_keys(c.packed), c.logodds, colors, labels, confs)

    # ------------------------------------------------------------------ multi-resolution
    def coarsen(self, levels: int = 1) -> SemanticOctoMap:
        """The map at ``resolution * 2**levels``, as OctoMap's inner nodes at that depth: occupancy = max of
        the children, colour = mean of the children's observations, semantics = fusion of the children's sets."""
        if not 0 <= levels <= 15:
            raise ConfigError(f"levels must be in 0..15, got {levels}")
        out = SemanticOctoMap(self.resolution * 2**levels, occupancy=self.occupancy, fusion=self.fusion,
                              label_set=self.label_set, max_range=self.max_range,
                              grid_cell_limit=self.grid_cell_limit, cell_evidence=self.cell_evidence)
        c = self.cells()
        if levels == 0 or c.packed.size == 0:
            out._load_cells(c)
            return out
        keys = unpack_keys(c.packed)
        coarse = pack_keys(((keys - TREE_MAX_VAL) >> levels) + TREE_MAX_VAL)
        order = np.argsort(coarse, kind="stable")
        packed, lo, attr, rgb, rgb_count, labels, probs = coarsen_cells(
            coarse[order], c.logodds[order], c.attr[order], c.rgb, c.rgb_count, c.sem_labels, c.sem_probs,
            self._entry.code, self._entry.layout_code, self._entry.kernels()[0], self._params)
        out._load_cells(CellArrays(packed, lo, attr, rgb, rgb_count, labels, probs))
        return out

    def _load_cells(self, c: CellArrays) -> None:
        """Replace the contents with compacted cells (used by coarsen and by file readers)."""
        packed = np.ascontiguousarray(c.packed, np.int64)
        per_shard = np.bincount(_shards_of(packed), minlength=ht.N_SHARDS) if packed.size else np.zeros(1)
        cap = ht.round_capacity(per_shard.max() / (ht.MAX_LOAD * 0.9) + 1)
        self._alloc_attributes(max(c.rgb_count.shape[0], 16))
        self._n_attr = int(c.rgb_count.shape[0])
        self._rgb[: self._n_attr] = c.rgb
        self._rgb_count[: self._n_attr] = c.rgb_count
        self._sem_labels[: self._n_attr] = c.sem_labels
        self._sem_probs[: self._n_attr] = c.sem_probs
        values, rows = np.ascontiguousarray(c.logodds, np.float32), np.ascontiguousarray(c.attr, np.int32)
        while True:
            self._alloc_table(cap)
            if _insert_cells(self._keys, self._logodds, self._attr, self._counts, cap, packed, values, rows):
                break
            cap = ht.round_capacity(cap * ht.GROWTH)

    @classmethod
    def from_cells(cls, resolution: float, cells: CellArrays, **kwargs) -> SemanticOctoMap:
        m = cls(resolution, **kwargs)
        m._load_cells(cells)
        return m

    # ------------------------------------------------------------------ the map interface (maps.base)
    def integrate(self, obs: Observation) -> dict[str, float]:
        """Insert one frame's observation (:meth:`insert_points`); milliseconds per insertion step."""
        self._tree_counts = None
        return self.insert_points(obs.points_world, obs.origin, colors=obs.colors, semantics=obs.semantics,
                                  clear=obs.clear_points).ms

    def cloud(self) -> MapCloud:
        """Occupied voxels: centres, mean colours, top class and its confidence, sorted by key."""
        v = self.voxels()
        return MapCloud(v.centers, v.colors, v.labels[:, 0].copy(), v.probs[:, 0].copy(), self.resolution)

    def file_tree(self) -> OctreeNodes:
        """The pruned tree the ``.ot``/``.bt`` files hold (voxel colour by ``color_mode``; ``semmap.io.map_files``
        writes them); :meth:`describe` then reuses its counts instead of building it again."""
        tree = self.tree(color_mode=self.color_mode)
        self._tree_counts = _tree_counts(tree, self.is_occupied(tree.values))
        return tree

    def describe(self) -> dict:
        """Pruned-tree leaves and nodes, voxel counts and memory (bytes per known voxel)."""
        if self._tree_counts is None:
            tree = self.tree(color_mode=self.color_mode)
            self._tree_counts = _tree_counts(tree, self.is_occupied(tree.values))
        return {**self._tree_counts, "occupied_voxels": self.num_occupied, "free_voxels": self.num_free,
                "bytes_in_memory": self.memory_bytes,
                "bytes_per_voxel_in_memory": round(self.memory_bytes / max(self.num_leaves, 1), 2),
                "fusion": self.fusion.name}

    def class_probs(self) -> np.ndarray:
        """(M, K) class distribution of each occupied voxel (:meth:`cloud` order): a set read as a K-vector with
        "others" spread over the classes outside it (``fusion.dense.expand_topk``), or the full-K state's."""
        if self.label_set is None:
            raise ConfigError("a map without a label set has no class distributions")
        c = self.cells()
        rows = c.attr[c.logodds >= self._thr]
        return self._entry.class_probs(*self._states(rows, c.sem_labels, c.sem_probs), self._num_classes)

    def class_probs_per_view(self) -> np.ndarray:
        """What the CRF reads: :meth:`class_probs` as they are, since the OctoMap already fuses one distribution
        per view and voxel (a per-pixel log-odds map divides its sum by its points per view instead)."""
        return self.class_probs()

    def set_class_probs(self, probs: np.ndarray, *, where: np.ndarray | None = None) -> None:
        """Replace the class states of the occupied voxels (:meth:`cloud` order; only rows ``where`` is True) by
        (M, K) distributions, e.g. a CRF's posterior, as the rule keeps them (a set: the top pairs, top confidence
        capped as fusion caps it)."""
        c = self.cells()
        rows = c.attr[c.logodds >= self._thr]
        sel = rows >= 0 if where is None else np.asarray(where, bool) & (rows >= 0)
        p = np.asarray(probs, np.float32)[sel]
        if self._entry.dense:
            labels, values = self._entry.from_probs(p, self.fusion)
        else:  # the top pairs of the distributions as given (no renormalisation: the paper's map as before)
            top = TopKProbs.from_dense(p, self._widths[0])
            labels, values = top.labels, np.minimum(top.probs, self.fusion.max_confidence)
        self._sem_labels[rows[sel]] = labels
        self._sem_probs[rows[sel]] = values
        self._tree_counts = None

    def __repr__(self) -> str:
        return (f"SemanticOctoMap(resolution={self.resolution}, leaves={self.num_leaves}, "
                f"occupied={self.num_occupied}, bytes={self.memory_bytes})")


def _tree_counts(tree: OctreeNodes, occupied: np.ndarray) -> dict[str, int]:
    leaf = tree.is_leaf
    return {"occupied_leaves": int((leaf & occupied).sum()), "free_leaves": int((leaf & ~occupied).sum()),
            "nodes": len(tree)}


@nb.njit(cache=True)
def _shards_of(packed):
    out = np.empty(packed.shape[0], np.int64)
    for i in range(packed.shape[0]):
        out[i] = ht.shard_of(packed[i])
    return out


@nb.njit(cache=True)
def _insert_cells(keys, logodds, attr, counts, shard_cap, packed, values, rows) -> bool:
    """Insert compacted cells into an empty table; False if a lane overflowed."""
    for i in range(packed.shape[0]):
        s = ht.find_or_insert(keys, logodds, attr, counts, ht.shard_of(packed[i]), shard_cap, packed[i])
        if s < 0:
            return False
        logodds[s] = values[i]
        attr[s] = rows[i]
    return True


def compile_kernels() -> float:
    """Run every insertion, growth and query path once on a tiny scan so numba compiles (or loads from its
    cache) all map kernels now rather than during the first frames; returns the seconds it took."""
    t = time.perf_counter()
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.0, 1.0, (4000, 3)) + np.array([0.0, 0.0, 2.0])
    labels = np.full((len(pts), 3), EMPTY_LABEL, np.uint16)
    labels[:, 0] = rng.integers(1, 4, len(pts))
    probs = np.zeros((len(pts), 3), np.float32)
    probs[:, 0] = 0.7
    colors = rng.integers(0, 255, (len(pts), 3), dtype=np.uint8)
    for max_range in (-1.0, 1.5):
        m = SemanticOctoMap(0.05, label_set=LabelSet.generic(4), max_range=max_range)
        m.insert_points(pts, np.zeros(3), colors=colors, semantics=TopKProbs(labels, probs))  # grows the table
        m.insert_points(pts, np.array([1e6, 0.0, 0.0]), colors=colors)  # hits only
    decaying = SemanticOctoMap(0.05, decay=0.1)
    for origin in (np.zeros(3), np.array([0.0, 0.0, 0.5])):
        decaying.insert_points(pts, origin)
    first = SemanticOctoMap(0.05, label_set=LabelSet.generic(4), cell_evidence=CellEvidence.FIRST)
    first.insert_points(pts, np.zeros(3), colors=colors, semantics=TopKProbs(labels, probs))
    m.state_at(pts[:8])
    m.semantics_at(pts[:8])
    m.coarsen(1)
    m.tree()
    kern.compile_parallel_variants(m._entry.code, *m._entry.kernels(), m._params)
    compile_mean_variants(m.fusion.k)
    return time.perf_counter() - t
