"""Sharded open-addressing hash table of finest-level voxels (numba, struct of arrays).

Each slot holds the packed key (int64, -1 = empty), the occupancy log-odds (float32) and an index into
the attribute arrays (int32, -1 = never hit, so free space carries no colour or semantics): 16 bytes.
The table is split into ``n_shards`` equal contiguous shards chosen by the top bits of the key hash, so
threads update disjoint shards without atomics, and a shard never changes when the table grows.
Within a shard the slot of a key is a hashed group of 8 slots indexed by the low 3 bits of z: cells of
a z-run sit side by side (locality for rays and scans).  A collision moves on to the same lane (z & 7) of the
next group, so the 8 cells of a z-run never push each other out of their places: each lane is an ordinary
linear-probing table.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from semmap.keys import KEY_LIMIT, coords_to_keys, pack_keys
from semmap.maps._keys import EMPTY_KEY
from semmap.maps._prefetch import prefetch

GROUP = 8  # slots per locality group (low bits of z)
SHARD_BITS = 6
N_SHARDS = 1 << SHARD_BITS
#: A shard is grown once it is fuller than this after a frame.
MAX_LOAD = 0.85
#: Before a frame, a shard that could exceed this with every new cell is grown first (probing safety).
HARD_LOAD = 0.95
GROWTH = 1.5
#: Load of the fullest shard when the table is sized at once for a scan's new cells (a first scan, a big one): between
#: a just-grown table's (MAX_LOAD / GROWTH) and the trigger, so that the next scans do not make it grow straight away.
SIZED_LOAD = MAX_LOAD / GROWTH**0.5


@nb.njit(cache=True, inline="always")
def key_hash(k: np.int64) -> np.uint64:
    """64-bit mix of (x, y, z >> 3): the same for the 8 cells of a z-group."""
    x = np.uint64(k & 0xFFFF)
    y = np.uint64((k >> 16) & 0xFFFF)
    zg = np.uint64((k >> 35) & 0x1FFF)
    h = x * np.uint64(0x9E3779B97F4A7C15) ^ y * np.uint64(0xC2B2AE3D27D4EB4F) ^ zg * np.uint64(0x165667B19E3779F9)
    h ^= h >> np.uint64(31)
    h *= np.uint64(0xD6E8FEB86659FD93)
    h ^= h >> np.uint64(32)
    return h


@nb.njit(cache=True, inline="always")
def shard_of(k: np.int64) -> np.int64:
    return np.int64(key_hash(k) >> np.uint64(64 - SHARD_BITS))


@nb.njit(cache=True, inline="always")
def home_slot(k: np.int64, shard_cap: int) -> np.int64:
    """Home slot of a key inside its shard (0 <= slot < shard_cap; shard_cap is a multiple of GROUP)."""
    h = key_hash(k) & np.uint64(0xFFFFFFFF)
    groups = np.uint64(shard_cap // GROUP)
    g = np.int64((h * groups) >> np.uint64(32))
    return g * GROUP + ((k >> 32) & (GROUP - 1))


@nb.njit(cache=True, inline="always")
def find_slot(keys: np.ndarray, shard_cap: int, k: np.int64) -> np.int64:
    """Slot of ``k`` or -1 when absent."""
    base = shard_of(k) * shard_cap
    s = home_slot(k, shard_cap)
    for _ in range(shard_cap // GROUP):
        v = keys[base + s]
        if v == k:
            return base + s
        if v == EMPTY_KEY:
            return -1
        s += GROUP
        if s >= shard_cap:
            s -= shard_cap
    return -1


@nb.njit(cache=True, inline="always")
def find_or_insert(keys: np.ndarray, logodds: np.ndarray, attr: np.ndarray, counts: np.ndarray,
                   shard: int, shard_cap: int, k: np.int64) -> np.int64:
    """Slot of ``k`` in its shard, inserting it (log-odds 0, no attributes) when absent; -1 if its lane is full
    (the caller grows the table and tries again)."""
    base = shard * shard_cap
    s = home_slot(k, shard_cap)
    for _ in range(shard_cap // GROUP):
        v = keys[base + s]
        if v == k:
            return base + s
        if v == EMPTY_KEY:
            keys[base + s] = k
            logodds[base + s] = 0.0
            attr[base + s] = -1
            counts[shard] += 1
            return base + s
        s += GROUP
        if s >= shard_cap:
            s -= shard_cap
    return -1


@nb.njit(cache=True, parallel=True)
def rehash(keys: np.ndarray, logodds: np.ndarray, attr: np.ndarray, shard_cap: int,
           new_keys: np.ndarray, new_logodds: np.ndarray, new_attr: np.ndarray, new_cap: int,
           counts: np.ndarray) -> bool:
    """Move every entry into a table with ``new_cap`` slots per shard (each shard in parallel); False if a
    lane of the new table overflowed (then try a bigger one)."""
    failed = np.zeros(N_SHARDS, np.bool_)
    for sh in nb.prange(N_SHARDS):
        counts[sh] = 0
        for i in range(sh * shard_cap, (sh + 1) * shard_cap):
            k = keys[i]
            if k != EMPTY_KEY:
                s = find_or_insert(new_keys, new_logodds, new_attr, counts, sh, new_cap, k)
                if s < 0:
                    failed[sh] = True
                    break
                new_logodds[s] = logodds[i]
                new_attr[s] = attr[i]
    return not failed.any()


@nb.njit(cache=True, parallel=True)
def lookup_many(keys: np.ndarray, shard_cap: int, packed: np.ndarray) -> np.ndarray:
    """Slots (or -1) of many packed keys."""
    out = np.empty(packed.shape[0], np.int64)
    for i in nb.prange(packed.shape[0]):
        out[i] = find_slot(keys, shard_cap, packed[i])
    return out


def slots_at(keys: np.ndarray, shard_cap: int, points: np.ndarray, resolution: float) -> np.ndarray:
    """Slot of the cell at ``resolution`` holding each (N, 3) world point; -1 where the table has none, the point is
    outside the key range or not finite."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    finite = np.isfinite(pts).all(axis=1)
    cell = coords_to_keys(np.where(finite[:, None], pts, 0.0), resolution)
    inside = ((cell >= 0) & (cell < KEY_LIMIT)).all(axis=1) & finite
    slots = np.full(pts.shape[0], -1, np.int64)
    if inside.any():
        slots[inside] = lookup_many(keys, shard_cap, pack_keys(cell[inside]))
    return slots


def round_capacity(n: float) -> int:
    """Shard capacity: at least GROUP, a multiple of GROUP."""
    return max(GROUP, int(np.ceil(n / GROUP)) * GROUP)


def next_capacity(shard_cap: int, min_cap: float) -> int:
    """Shard capacity after growing from ``shard_cap``: by the growth factor at least, and to ``min_cap`` when that
    is more (not by repeated steps from a tiny table, which could overshoot by the whole factor)."""
    return max(round_capacity(min_cap), round_capacity(shard_cap * GROWTH))


class ShardedTable:
    """The sharded table's arrays and their growth, for maps that hold their own voxels (voxel grid, point map).

    ``keys`` / ``logodds`` / ``attr`` are the slots (see the module docstring), ``counts`` the entries per shard.
    """

    def __init__(self, shard_cap: int = GROUP) -> None:
        self.alloc(round_capacity(shard_cap))

    def alloc(self, shard_cap: int) -> None:
        n = N_SHARDS * shard_cap
        self.shard_cap = shard_cap
        self.keys = np.full(n, EMPTY_KEY, np.int64)
        self.logodds = np.zeros(n, np.float32)
        self.attr = np.full(n, -1, np.int32)
        self.counts = np.zeros(N_SHARDS, np.int64)

    @property
    def fill_limit(self) -> int:
        """Entries a shard may hold before it must grow (keeps linear probing short)."""
        return int(HARD_LOAD * self.shard_cap)

    @property
    def nbytes(self) -> int:
        return int(self.keys.nbytes + self.logodds.nbytes + self.attr.nbytes + self.counts.nbytes)

    def grow(self, min_cap: int) -> None:
        """Rehash into shards of at least ``min_cap`` slots and the growth factor (more if a lane overflows)."""
        cap = next_capacity(self.shard_cap, min_cap)
        old = (self.keys, self.logodds, self.attr, self.shard_cap)
        while True:
            self.alloc(cap)
            if rehash(old[0], old[1], old[2], old[3], self.keys, self.logodds, self.attr, cap, self.counts):
                return
            cap = round_capacity(cap * GROWTH)

    def settle(self) -> bool:
        """Grow once after a frame if the fullest shard is past the normal load; True if the table moved."""
        if self.counts.max() > MAX_LOAD * self.shard_cap:
            self.grow(round_capacity(self.shard_cap * GROWTH))
            return True
        return False

    def used(self) -> np.ndarray:
        """Slots holding a key."""
        return np.flatnonzero(self.keys != EMPTY_KEY)

    def load(self, packed: np.ndarray, logodds: np.ndarray, attr: np.ndarray) -> None:
        """Replace the contents with the given (unique) keys, values and attribute rows."""
        packed = np.ascontiguousarray(packed, np.int64)
        per_shard = np.bincount(shards_of(packed), minlength=N_SHARDS) if packed.size else np.zeros(1)
        cap = round_capacity(per_shard.max() / (MAX_LOAD * 0.9) + 1)
        values, rows = np.ascontiguousarray(logodds, np.float32), np.ascontiguousarray(attr, np.int32)
        while True:
            self.alloc(cap)
            if insert_all(self.keys, self.logodds, self.attr, self.counts, cap, packed, values, rows):
                return
            cap = round_capacity(cap * GROWTH)


@nb.njit(cache=True)
def shards_of(packed: np.ndarray) -> np.ndarray:
    """Shard of each packed key."""
    out = np.empty(packed.shape[0], np.int64)
    for i in range(packed.shape[0]):
        out[i] = shard_of(packed[i])
    return out


@nb.njit(cache=True)
def insert_all(keys, logodds, attr, counts, shard_cap, packed, values, rows) -> bool:
    """Insert (unique) keys with their values and rows into an empty table; False if a lane overflowed."""
    for i in range(packed.shape[0]):
        s = find_or_insert(keys, logodds, attr, counts, shard_of(packed[i]), shard_cap, packed[i])
        if s < 0:
            return False
        logodds[s] = values[i]
        attr[s] = rows[i]
    return True


@nb.njit(cache=True, inline="always")
def prefetch_home(keys: np.ndarray, logodds: np.ndarray, shard: int, shard_cap: int, k: np.int64) -> None:
    """Start fetching the cache lines where ``k``'s key and log-odds live (or would be inserted) in ``shard``:
    a pass over many keys calls it some keys ahead, so their misses overlap."""
    s = shard * shard_cap + home_slot(k, shard_cap)
    prefetch(keys, s)
    prefetch(logodds, s)
