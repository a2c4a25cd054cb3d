"""Sparse hashed voxels with colour, hits and a fused class distribution: the core of the voxel grid and point map.

Voxels live in the octree's sharded hash table (:class:`~semmap.maps._hashtable.ShardedTable`, OctoMap keys
from ``maps/_keys.py``), so they line up with the semantic OctoMap's voxels and with the simulator's ground
truth.  Each voxel owns one attribute row: mean colour + colour count, hits (frames that saw it), and the state
of its fusion rule (``fusion/``): K numbers (log-odds or votes, float16 or float32) for the full-K rules, or
(label, confidence) pairs for ``topk`` / ``max``; the point map adds a mean position and a normal sum.
Every point of a frame counts (eq. 2's sum over all measurements in the cell), not only the first.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from semmap.errors import ConfigError
from semmap.fusion.dense import expand_topk, logodds_to_probs
from semmap.fusion.half import from_half_bits, to_half_bits
from semmap.fusion.rules import FusionParams, FusionRule
from semmap.keys import keys_to_coords, unpack_keys
from semmap.maps import _grid_kernels as kern
from semmap.maps._hashtable import GROWTH, MAX_LOAD, N_SHARDS, ShardedTable, lookup_many, round_capacity, slots_at
from semmap.maps.base import MapState, check_state, restore_arrays
from semmap.types import EMPTY_LABEL, LabelSet, TopKProbs

#: Storage types of the per-class state.
DTYPES = ("float16", "float32")
#: OctoMap's hit log-odds (p = 0.7) and upper clamp (p = 0.971): a voxel is occupied once hit.
HIT_LOGODDS = np.float32(0.8472979)
CLAMP_MAX_LOGODDS = np.float32(3.5138063)
_INITIAL_ROWS = 64  # attribute rows of an empty grid; they grow by half as voxels come


@dataclass(frozen=True)
class GridArrays:
    """Every stored voxel in key order, as a file writer or a comparison needs them (lossless)."""

    packed: np.ndarray  # (M,) int64 packed keys
    logodds: np.ndarray  # (M,) float32 hit log-odds
    rgb: np.ndarray  # (M, 3) uint8
    rgb_count: np.ndarray  # (M,) uint16
    hits: np.ndarray  # (M,) uint16 frames that hit the voxel (saturating)
    dense: np.ndarray  # (M, K) float32 or uint16 float16 bits; (M, 0) for the set rules
    set_labels: np.ndarray  # (M, S) uint16
    set_probs: np.ndarray  # (M, S) float32 or uint16 float16 bits
    positions: np.ndarray  # (M, 3) float32 mean point (point map) or (M, 0)
    normal_sums: np.ndarray  # (M, 3) float32 summed normals (point map) or (M, 0)

    def select(self, sel: np.ndarray) -> GridArrays:
        """The voxels picked by a boolean mask or index array."""
        return GridArrays(*(getattr(self, f)[sel] for f in GridArrays.__dataclass_fields__))


class SemanticGrid:
    """Hashed semantic voxels at ``resolution`` fused by ``fusion`` (see the module docstring).

    ``dtype`` is the storage of the per-class numbers (float16 halves the memory of the full-K rules);
    ``keep_geometry`` keeps each voxel's mean point and normal (the point map).
    """

    def __init__(self, resolution: float, *, label_set: LabelSet | None, fusion: FusionParams | None = None,
                 dtype: str = "float32", keep_geometry: bool = False) -> None:
        if not (np.isfinite(resolution) and 0.001 <= resolution <= 10.0):
            raise ConfigError(f"resolution must be between 0.001 and 10 m, got {resolution}")
        if dtype not in DTYPES:
            raise ConfigError(f"state dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
        self.resolution = float(resolution)
        self.label_set = label_set
        self.fusion = fusion or FusionParams()
        self.dtype = dtype
        self.keep_geometry = keep_geometry
        self.num_classes = len(label_set) if label_set is not None else 0
        self._params = self.fusion.kernel_params(self.num_classes)
        self._table = ShardedTable()
        self._rows = 0
        self._alloc_rows(_INITIAL_ROWS)
        self._keys_buf = np.zeros((2, 0), np.int64)

    # ------------------------------------------------------------------ storage
    @property
    def _entry(self):
        """The fusion rule's registry entry (looked up, not held: a checkpoint saves the map's plain state)."""
        return self.fusion.entry

    @property
    def _half(self) -> bool:
        return self.dtype == "float16"

    def _widths(self) -> tuple[int, int]:
        """(K numbers, S pairs) per voxel for the fusion rule."""
        if self.num_classes == 0:
            return 0, 0
        s, w = self._entry.widths(self.fusion, self.num_classes)
        return (w, 0) if self._entry.dense else (0, s)

    def _alloc_rows(self, n: int) -> None:
        K, S = self._widths()
        state_t = np.uint16 if self._half else np.float32
        g = 3 if self.keep_geometry else 0
        fresh = {
            "rgb": np.zeros((n, 3), np.uint8), "rgb_count": np.zeros(n, np.uint16), "hits": np.zeros(n, np.uint16),
            "dense": np.zeros((n, K), state_t), "set_labels": np.full((n, S), EMPTY_LABEL, np.uint16),
            "set_probs": np.zeros((n, S), state_t), "positions": np.zeros((n, g), np.float32),
            "normal_sums": np.zeros((n, g), np.float32),
        }
        for name, arr in fresh.items():
            old = getattr(self, f"_{name}", None)
            if old is not None:
                arr[: self._rows] = old[: self._rows]
            setattr(self, f"_{name}", arr)

    def _ensure_rows(self, n: int) -> None:
        have = self._hits.shape[0]
        if n > have:
            self._alloc_rows(max(n, int(have * 1.5)))

    # ------------------------------------------------------------------ checkpoints
    #: Checkpoint schema: stable name -> attribute holding it (tests check that it covers every array the grid holds).
    STATE_ARRAYS: ClassVar[dict[str, str]] = {
        "rgb": "_rgb", "rgb_count": "_rgb_count", "hits": "_hits", "dense": "_dense", "set_labels": "_set_labels",
        "set_probs": "_set_probs", "positions": "_positions", "normal_sums": "_normal_sums"}

    def state(self) -> MapState:
        """Everything integration changes, by the checkpoint schema's names (hash table layout included)."""
        t = self._table
        return {**{name: getattr(self, attr) for name, attr in self.STATE_ARRAYS.items()},
                "table_keys": t.keys, "table_logodds": t.logodds, "table_rows": t.attr, "shard_counts": t.counts,
                "shard_capacity": np.int64(t.shard_cap), "rows_used": np.int64(self._rows)}

    def restore(self, state: MapState) -> None:
        """Continue from :meth:`state` of a grid built with the same parameters."""
        table = ("table_keys", "table_logodds", "table_rows", "shard_counts", "shard_capacity", "rows_used")
        check_state(state, (*self.STATE_ARRAYS, *table), "a voxel grid")
        restore_arrays(self, self.STATE_ARRAYS, state, "a voxel grid", "grid")
        t = self._table
        t.keys, t.logodds = np.ascontiguousarray(state["table_keys"]), np.ascontiguousarray(state["table_logodds"])
        t.attr, t.counts = np.ascontiguousarray(state["table_rows"]), np.ascontiguousarray(state["shard_counts"])
        t.shard_cap, self._rows = int(state["shard_capacity"]), int(state["rows_used"])

    @property
    def memory_bytes(self) -> int:
        """Bytes held: hash table (with its slack) and attribute rows (allocated, not only used)."""
        rows = (self._rgb, self._rgb_count, self._hits, self._dense, self._set_labels, self._set_probs,
                self._positions, self._normal_sums)
        return self._table.nbytes + int(sum(a.nbytes for a in rows))

    @property
    def num_voxels(self) -> int:
        return self._rows

    # ------------------------------------------------------------------ integration
    def integrate_points(self, points: np.ndarray, *, colors: np.ndarray | None = None,
                         semantics: TopKProbs | None = None, normals: np.ndarray | None = None) -> dict[str, float]:
        """Fuse one frame's world points (N, 3) with optional colours (N, 3) uint8, class sets (N, k) and
        normals (N, 3); returns milliseconds per step."""
        t0 = time.perf_counter()
        pts, col, sem_l, sem_p, nrm = self._validated(points, colors, semantics, normals)
        order, bucket_keys, offsets = self._bucketed(pts)
        if sem_l.shape[0] == 0 and not self.keep_geometry:  # colour at most (the dense cloud): once per voxel
            return self._integrate_merged(order, bucket_keys, offsets, col, t0)
        sorted_pts, sorted_keys = np.empty_like(order), np.empty_like(order)
        voxels = np.zeros(N_SHARDS, np.int64)
        kern.group_shards(order, bucket_keys, offsets, sorted_pts, sorted_keys, voxels)
        t1 = time.perf_counter()
        run_slot, new_rows = self._find_voxels(sorted_keys, offsets, offsets[1:], voxels)
        first_row = self._reserve_rows(new_rows)
        t2 = time.perf_counter()
        e = self._entry
        update, finish = e.kernels()
        t = self._table
        kern.fuse_points(t.attr, t.logodds, sorted_pts, offsets, run_slot, sorted_keys, first_row, pts,
                         col if col is not None else np.zeros((1, 3), np.uint8), col is not None,
                         sem_l, sem_p, sem_l.shape[0] > 0 and self.num_classes > 0,
                         nrm if nrm is not None else np.zeros((1, 3), np.float32), nrm is not None,
                         self._rgb, self._rgb_count, self._hits,
                         self._dense if not self._half else np.zeros((1, self._dense.shape[1]), np.float32),
                         self._dense if self._half else np.zeros((1, self._dense.shape[1]), np.uint16),
                         self._set_labels,
                         self._set_probs if not self._half else np.zeros((1, self._set_probs.shape[1]), np.float32),
                         self._set_probs if self._half else np.zeros((1, self._set_probs.shape[1]), np.uint16),
                         self._half, self._positions, self._normal_sums, self.keep_geometry,
                         e.code, e.layout_code, update, finish, self._params, HIT_LOGODDS, CLAMP_MAX_LOGODDS)
        self._rows += int(new_rows.sum())
        t.settle()  # grow after the frame if a shard is past the normal load
        t3 = time.perf_counter()
        return {"keys": (t1 - t0) * 1e3, "hash": (t2 - t1) * 1e3, "fuse": (t3 - t2) * 1e3}

    def _bucketed(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frame's valid points grouped by hash shard: (point indices, their packed keys, shard offsets)."""
        n = pts.shape[0]
        if self._keys_buf.shape[1] < n:
            self._keys_buf = np.empty((2, int(n * 1.25) + 16), np.int64)
        packed, shard = self._keys_buf[0, :n], self._keys_buf[1, :n]
        kern.point_keys(pts, 1.0 / self.resolution, packed, shard)
        return kern.bucket_by_shard(packed, shard)

    def _integrate_merged(self, order: np.ndarray, bucket_keys: np.ndarray, offsets: np.ndarray,
                          col: np.ndarray | None, t0: float) -> dict[str, float]:
        """:meth:`integrate_points` for a frame without classes into a grid without geometry (the dense cloud):
        the points merged per voxel first (count, summed colour), so the table and the rows are visited once per
        voxel; the same voxels, rows and numbers as the per-point path."""
        n = bucket_keys.shape[0]
        vox_keys, vox_points = np.empty(n, np.int64), np.empty(n, np.int64)
        vox_rgb = np.empty((n, 3), np.int64)
        voxels = np.zeros(N_SHARDS, np.int64)
        colors = col if col is not None else np.zeros((1, 3), np.uint8)
        kern.merge_voxels(order, bucket_keys, offsets, colors, col is not None, vox_keys, vox_points, vox_rgb,
                          voxels)
        t1 = time.perf_counter()
        slot, new_rows = self._find_voxels(vox_keys, offsets, offsets[:-1] + voxels, voxels)
        first_row = self._reserve_rows(new_rows)
        t2 = time.perf_counter()
        t = self._table
        kern.fuse_voxels(t.attr, t.logodds, offsets, voxels, slot, first_row, vox_points, vox_rgb, col is not None,
                         self._rgb, self._rgb_count, self._hits, HIT_LOGODDS, CLAMP_MAX_LOGODDS)
        self._rows += int(new_rows.sum())
        t.settle()
        t3 = time.perf_counter()
        return {"keys": (t1 - t0) * 1e3, "hash": (t2 - t1) * 1e3, "fuse": (t3 - t2) * 1e3}

    def _reserve_rows(self, new_rows: np.ndarray) -> np.ndarray:
        """Room for a frame's new voxels (``new_rows`` per shard, rows handed out in shard order); returns each
        shard's first new row."""
        self._ensure_rows(self._rows + int(new_rows.sum()))
        return self._rows + np.concatenate([[0], np.cumsum(new_rows)[:-1]])

    def _find_voxels(self, sorted_keys: np.ndarray, offsets: np.ndarray, ends: np.ndarray,
                     voxels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Slot of every voxel of the frame (at its first point's position; shard s's keys are
        ``sorted_keys[offsets[s]:ends[s]]``) and new voxels per shard; the table grows first if every voxel could be
        new, and again if a lane fills up."""
        t = self._table
        if ((t.counts + voxels) > t.fill_limit).any():
            t.grow(round_capacity(((t.counts + voxels) / MAX_LOAD).max()))
        run_slot = np.full(sorted_keys.shape[0], -1, np.int64)
        new_rows = np.zeros(N_SHARDS, np.int64)
        failed = np.zeros(N_SHARDS, np.bool_)
        while True:
            kern.find_voxels(t.keys, t.logodds, t.attr, t.counts, t.shard_cap, sorted_keys, offsets, ends, run_slot,
                             new_rows, failed)
            if not failed.any():
                return run_slot, new_rows
            t.grow(round_capacity(t.shard_cap * GROWTH))  # a lane overflowed (very uneven keys)

    def _validated(self, points, colors, semantics, normals):
        pts = np.asarray(points)
        pts = np.ascontiguousarray(pts, dtype=pts.dtype if pts.dtype in (np.float32, np.float64) else np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ConfigError(f"points must be (N, 3), got {pts.shape}")
        n = pts.shape[0]
        col = nrm = None
        if colors is not None:
            col = np.ascontiguousarray(colors, dtype=np.uint8)
            if col.shape != (n, 3):
                raise ConfigError(f"colours must be ({n}, 3), got {col.shape}")
        if normals is not None and self.keep_geometry:
            nrm = np.ascontiguousarray(normals, dtype=np.float32)
            if nrm.shape != (n, 3):
                raise ConfigError(f"normals must be ({n}, 3), got {nrm.shape}")
        k = max(self.fusion.k if self._entry.sets_of_k else 1, 1)
        sem_l = np.zeros((0, k), np.uint16)
        sem_p = np.zeros((0, k), np.float32)
        if semantics is not None and self.num_classes > 0:
            sem_l = np.ascontiguousarray(semantics.labels, dtype=np.uint16)
            sem_p = np.ascontiguousarray(semantics.probs, dtype=np.float32)
            if sem_l.ndim != 2 or sem_l.shape[0] != n:
                raise ConfigError(f"class sets must be ({n}, k), got {sem_l.shape}")
            if self._entry.sets_of_k and sem_l.shape[1] != self.fusion.k:
                raise ConfigError(f"{self._entry.name} fusion with k = {self.fusion.k} needs class sets of "
                                  f"{self.fusion.k}, got {sem_l.shape[1]}")
            if sem_l.shape[1] == 0:
                raise ConfigError("class sets must hold at least one (label, probability) pair")
            bad = (sem_l != EMPTY_LABEL) & (sem_l >= self.num_classes)
            if bad.any():
                raise ConfigError(f"class id {int(sem_l[bad].max())} is outside the map's label set "
                                  f"({self.num_classes} classes)")
        return pts, col, sem_l, sem_p, nrm

    # ------------------------------------------------------------------ queries
    def arrays(self) -> GridArrays:
        """Every voxel, compacted and sorted by key (deterministic)."""
        t = self._table
        used = t.used()
        return self.arrays_at(used[np.argsort(t.keys[used], kind="stable")])

    def arrays_at(self, slots: np.ndarray) -> GridArrays:
        """The voxels in the given table slots (each holding a voxel, e.g. from :meth:`slots_at`), in that order."""
        t = self._table
        rows = t.attr[slots]
        return GridArrays(t.keys[slots].copy(), t.logodds[slots].copy(), self._rgb[rows], self._rgb_count[rows],
                          self._hits[rows], self._dense[rows], self._set_labels[rows], self._set_probs[rows],
                          self._positions[rows], self._normal_sums[rows])

    def slots_at(self, points: np.ndarray) -> np.ndarray:
        """Table slot of the voxel holding each (N, 3) world point, -1 where the grid has none."""
        pts = np.asarray(points, np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ConfigError(f"query points must be (N, 3), got {pts.shape}")
        return slots_at(self._table.keys, self._table.shard_cap, pts, self.resolution)

    def class_at(self, points: np.ndarray, keep: Callable[[GridArrays], np.ndarray] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Most probable class (EMPTY_LABEL where none) and its probability of the voxel holding each (N, 3)
        world point; voxels that are absent, or that ``keep`` (a mask over their arrays) drops, give none."""
        slots = self.slots_at(points)
        labels = np.full(slots.shape[0], EMPTY_LABEL, np.uint16)
        conf = np.zeros(slots.shape[0], np.float32)
        known = np.flatnonzero(slots >= 0)
        a = self.arrays_at(slots[known])
        top, p, _ = self.summary(a)
        if keep is not None:
            known, top, p = (v[keep(a)] for v in (known, top, p))
        labels[known], conf[known] = top, p
        return labels, conf

    def load_arrays(self, a: GridArrays) -> None:
        """Replace the contents (file readers)."""
        m = a.packed.shape[0]
        self._rows = 0
        for name in ("_rgb", "_rgb_count", "_hits", "_dense", "_set_labels", "_set_probs", "_positions",
                     "_normal_sums"):
            setattr(self, name, None)
        self._alloc_rows(max(m, 16))
        self._rows = m
        self._rgb[:m], self._rgb_count[:m], self._hits[:m] = a.rgb, a.rgb_count, a.hits
        self._dense[:m], self._set_labels[:m], self._set_probs[:m] = a.dense, a.set_labels, a.set_probs
        self._positions[:m], self._normal_sums[:m] = a.positions, a.normal_sums
        self._table.load(a.packed, a.logodds, np.arange(m, dtype=np.int32))

    def summary(self, a: GridArrays) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(most probable class (EMPTY where no evidence), its probability, entropy in nats) per voxel."""
        m = a.packed.shape[0]
        labels = np.full(m, EMPTY_LABEL, np.uint16)
        conf = np.zeros(m, np.float32)
        ent = np.zeros(m, np.float32)
        if self.num_classes == 0 or m == 0:
            return labels, conf, ent
        if self._entry.dense:
            rows = np.arange(m, dtype=np.int64)
            dense = np.ascontiguousarray(a.dense)
            f32 = dense if not self._half else np.zeros((1, dense.shape[1]), np.float32)
            u16 = dense if self._half else np.zeros((1, dense.shape[1]), np.uint16)
            kern.dense_summary(f32, u16, self._half, rows, self._entry.layout == "logodds", labels, conf, ent)
            return labels, conf, ent
        probs = self._set_probs_f32(a)
        has = a.set_labels[:, 0] != EMPTY_LABEL
        labels[has] = a.set_labels[has, 0]
        conf[has] = probs[has, 0]
        full = expand_topk(a.set_labels[has], probs[has], self.num_classes)
        ent[has] = -(full * np.log(full)).sum(1) / full.sum(1) + np.log(full.sum(1))
        return labels, conf, ent

    def _set_probs_f32(self, a: GridArrays) -> np.ndarray:
        return from_half_bits(a.set_probs) if self._half else a.set_probs.astype(np.float32)

    def class_probs(self, a: GridArrays) -> np.ndarray:
        """(M, K) class distribution of every voxel (the set rules' sets read as K-vectors)."""
        if self._entry.dense:
            return self._entry.class_probs(a.set_labels, from_half_bits(a.dense) if self._half else a.dense,
                                           self.num_classes)
        return self._entry.class_probs(a.set_labels, self._set_probs_f32(a), self.num_classes)

    def points_per_view(self, a: GridArrays) -> np.ndarray:
        """(M,) float64 measurements each voxel's distribution sums per view: its points over the frames that saw
        it for a log-odds rule (``bayes``, ``bayes-prior``: every pixel adds its log-probabilities), else 1.

        Why: the pixels one frame puts in a voxel repeat one view's evidence (same object, same network, same
        moment), so a per-pixel sum is far more certain than the views justify (at 5 cm, 100-200 pixels a frame);
        the CRF divides the log-probabilities by this to weigh each view once, as the OctoMap fuses them. Both
        counts saturate at 65535 (points first: the ratio then falls towards 1)."""
        out = np.ones(a.packed.shape[0], np.float64)
        if self._entry.layout == "logodds":
            seen = (a.hits > 0) & (a.rgb_count > 0)
            out[seen] = np.maximum(a.rgb_count[seen].astype(np.float64) / a.hits[seen], 1.0)
        return out

    def class_probs_per_view(self, a: GridArrays) -> np.ndarray:
        """(M, K) class distributions with a log-odds rule's state divided by :meth:`points_per_view` (from the
        log-odds themselves: the summed ones underflow float32 probabilities); other rules' as :meth:`class_probs`."""
        if self._entry.layout != "logodds" or self.num_classes == 0:
            return self.class_probs(a)
        h = (from_half_bits(a.dense) if self._half else a.dense).astype(np.float64)
        return logodds_to_probs(h / self.points_per_view(a)[:, None]).astype(np.float32)

    def set_class_probs(self, packed: np.ndarray, probs: np.ndarray) -> None:
        """Replace the class distributions of the voxels with keys ``packed`` by ``probs`` (M, K) (e.g. a CRF's
        posterior): log-odds, vote shares scaled to the cap, or the top pairs, as the rule keeps them."""
        t = self._table
        if len(packed) == 0:
            return
        slots = lookup_many(t.keys, t.shard_cap, np.ascontiguousarray(packed, np.int64))
        if (slots < 0).any():
            raise ConfigError("set_class_probs: some voxels are not in the map")
        rows = t.attr[slots]
        labels, values = self._entry.from_probs(probs, self.fusion)
        if self._entry.dense:
            self._dense[rows] = to_half_bits(values) if self._half else values
            return
        self._set_labels[rows] = labels
        self._set_probs[rows] = to_half_bits(values) if self._half else values

    def centers(self, a: GridArrays) -> np.ndarray:
        return keys_to_coords(unpack_keys(a.packed), self.resolution)


def _compile_normals() -> None:
    """The depth-image normals the point map asks the pipeline for."""
    from semmap.geometry import pixel_normals
    from semmap.types import CameraIntrinsics

    cam = CameraIntrinsics(8, 6, 5.0, 5.0, 3.5, 2.5)
    pixel_normals(np.ones((6, 8), np.float32), cam, np.eye(4), np.arange(48, dtype=np.int64))


def compile_kernels() -> float:
    """Run every grid kernel once on a tiny scan (each rule, both dtypes) so numba compiles or loads them now."""
    t = time.perf_counter()
    rng = np.random.default_rng(0)
    pts = (rng.uniform(-1.0, 1.0, (3000, 3)) + np.array([0.0, 0.0, 2.0])).astype(np.float32)  # as back-projected
    labels = np.full((len(pts), 3), EMPTY_LABEL, np.uint16)
    labels[:, 0] = rng.integers(1, 4, len(pts))
    probs = np.zeros((len(pts), 3), np.float32)
    probs[:, 0] = 0.7
    colors = rng.integers(0, 255, (len(pts), 3), dtype=np.uint8)
    normals = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (len(pts), 1))
    for dtype in DTYPES:
        for rule in FusionRule:
            g = SemanticGrid(0.05, label_set=LabelSet.generic(4), fusion=FusionParams(rule), dtype=dtype,
                             keep_geometry=rule == FusionRule.BAYES_PRIOR)
            for points in (pts, pts.astype(np.float64)):
                g.integrate_points(points, colors=colors, semantics=TopKProbs(labels, probs), normals=normals)
            a = g.arrays()
            g.summary(a)
    _compile_normals()
    return time.perf_counter() - t


class OnSemanticGrid:
    """A map whose classes and colours live in a :class:`SemanticGrid` ``self.grid`` (voxel grid, point map): its
    resolution, label set and fusion rule are the grid's."""

    grid: SemanticGrid

    @property
    def resolution(self) -> float:
        return self.grid.resolution

    @property
    def label_set(self) -> LabelSet | None:
        return self.grid.label_set

    @property
    def fusion(self) -> FusionParams:
        return self.grid.fusion
