"""The OctoMap's mean class evidence per endpoint cell and scan (numba): ``CellEvidence.MEAN``.

Every point of a cell counts: the cell's measurement is the mean of its points' top-k class distributions
(classes outside a point's set count 0 for it), as the k most probable classes of the mean (ties: the lower
class id); a cell of one point keeps that point's set as given.  Three passes, each on one chunk of points or
cells per thread:

1. the columns of sums: one per class id below ``num_classes`` when they are few (``DIRECT_COLUMNS``), else one
   per class the scan names (``_named_part``);
2. ``_sum_part``: each point's count and probabilities added in float64 to its cell's row of sums.  A point's
   cell is the previous point's when its key is the same (as it mostly is for neighbouring pixels), else a
   lookup in a small table of the scan's cells; a run of points of one cell with the same set keeps its sums
   in registers and stores them once at its end (the same additions, without a store and reload per point).
   A point of a cell first met in an earlier chunk is left for ``_add_deferred``, which adds those after all
   chunks, chunk by chunk: so every sum adds its points in input order, the order of a gather per cell, and
   the result is the same to the bit whatever the number of threads;
3. ``_largest_part``: each cell's k largest sums, divided by its points.

The loops call no helper that takes arrays: numba counts references on every such call, which costs more than
the work of a point.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from semmap.maps._keys import pack_key

#: Points from which the passes run on every thread (below that, waking them costs about what it saves).
PARALLEL_MIN = 32768
#: Class ids a uint16 label can hold (the columns of sums are looked up by label).
LABEL_RANGE = 1 << 16
#: Largest set (k) whose runs of equal sets are summed in registers; larger sets add point by point.
RUN_K = 4
#: Most classes that get a column each without looking which ones the scan names.
DIRECT_COLUMNS = 64


def cell_mean_sets(keys: np.ndarray, valid: np.ndarray, packed: np.ndarray, first: np.ndarray,
                   sem_labels: np.ndarray, sem_probs: np.ndarray, num_classes: int, empty: int,
                   n_threads: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean evidence of the endpoint cells ``packed`` (m,) of a scan, whose first points are ``first`` (m,),
    increasing (``scan_endpoints``' order), from the points' keys (N, 3), ``valid`` (N,) and top-k sets (N, k)
    (labels ``>= num_classes`` and ``empty`` ignored).  Returns (m, k) labels (``empty`` where fewer classes)
    and float32 probabilities, the same for any ``n_threads``."""
    parts = max(1, min(n_threads, packed.shape[0])) if valid.shape[0] >= PARALLEL_MIN else 1
    return _mean_sets(keys, valid, packed, first, sem_labels, sem_probs, num_classes, empty, parts)


def _mean_sets(keys, valid, packed, first, sem_labels, sem_probs, num_classes: int, empty: int,
               parts: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cell_mean_sets` in ``parts`` chunks, on as many threads (one: the serial variants)."""
    n, m, k = valid.shape[0], packed.shape[0], sem_labels.shape[1]
    num_classes = min(num_classes, LABEL_RANGE)
    named = np.ones((1, num_classes), np.uint8)  # few classes: a column each
    if num_classes > DIRECT_COLUMNS:
        named = np.zeros((parts, num_classes), np.uint8)
        (_named_parallel if parts > 1 else _named_serial)(sem_labels, named)
    column, class_of, n_cols = _columns(named, empty)
    table_keys, table_cells, mask = _cell_table(packed)
    count = np.zeros(m, np.int64)
    sums = np.empty((m, n_cols), np.float64)  # a sum starts at its first addition (seen)
    seen = np.zeros((m, (n_cols + 63) // 64), np.uint64)  # one bit per column
    deferred = np.empty(n if parts > 1 else 0, np.int64)  # chunk p's points of earlier chunks' cells, from p's start
    n_deferred = np.zeros(parts, np.int64)
    # the cells first met before each chunk (first is increasing): a chunk defers the points of those
    older = np.searchsorted(first, [_chunk(p, parts, n)[0] for p in range(parts)]).astype(np.int64)
    set_size = np.empty((1,) * min(k, RUN_K + 1), np.bool_)  # its ndim: k, a constant of the compiled loop
    (_sum_parallel if parts > 1 else _sum_serial)(keys, valid, table_keys, table_cells, mask, sem_labels, sem_probs,
                                                  column, older, count, sums, seen, deferred, n_deferred, set_size)
    if n_deferred.any():
        _add_deferred(keys, table_keys, table_cells, mask, sem_labels, sem_probs, column, count, sums, seen,
                      deferred, n_deferred)
    out_labels = np.full((m, k), empty, np.uint16)
    out_probs = np.zeros((m, k), np.float32)
    (_largest_parallel if parts > 1 else _largest_serial)(sem_labels, sem_probs, first, count, sums, seen, class_of,
                                                          out_labels, out_probs, parts)
    return out_labels, out_probs


@nb.njit(cache=True, inline="always")
def _chunk(part: int, parts: int, n: int) -> tuple[int, int]:
    """Items ``lo .. hi`` of chunk ``part`` of ``n`` items in ``parts`` chunks."""
    size = (n + parts - 1) // parts
    return min(n, part * size), min(n, (part + 1) * size)


@nb.njit(cache=True, inline="always")
def _slot(p: np.int64, mask: int) -> int:
    """Home slot of packed key ``p`` in a power-of-two table (Fibonacci hashing)."""
    return int((np.uint64(p) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(40)) & mask


@nb.njit(cache=True, nogil=True)
def _cell_table(packed: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Open-addressing table (keys, cell indices, mask) of the cells ``packed``, at most half full."""
    m = packed.shape[0]
    cap = 16
    while cap < 2 * m:
        cap *= 2
    mask = cap - 1
    table_keys = np.full(cap, -1, np.int64)
    table_cells = np.empty(cap, np.int32)
    for j in range(m):
        h = _slot(packed[j], mask)
        while table_keys[h] != -1:
            h = (h + 1) & mask
        table_keys[h] = packed[j]
        table_cells[h] = j
    return table_keys, table_cells, mask


@nb.njit(cache=True, inline="always")
def _named_part(part: int, sem_labels, named) -> None:
    """Pass 1 for chunk ``part`` of the points: mark the classes below ``named``'s width their sets name."""
    labels = sem_labels.reshape(-1)
    lo, hi = _chunk(part, named.shape[0], labels.shape[0])
    for i in range(lo, hi):
        if labels[i] < named.shape[1]:
            named[part, labels[i]] = 1


@nb.njit(cache=True, parallel=True, nogil=True)
def _named_parallel(sem_labels, named) -> None:
    for part in nb.prange(named.shape[0]):
        _named_part(part, sem_labels, named)


@nb.njit(cache=True, nogil=True)
def _named_serial(sem_labels, named) -> None:
    _named_part(0, sem_labels, named)


@nb.njit(cache=True, nogil=True)
def _columns(named: np.ndarray, empty: int) -> tuple[np.ndarray, np.ndarray, int]:
    """A column of sums for each class any part named (``named`` (parts, classes)), in ascending order:
    ``column[label]`` (-1: none, for every uint16 label) and ``class_of[column]``, and the number of columns."""
    column = np.full(LABEL_RANGE, -1, np.int32)
    class_of = np.empty(named.shape[1], np.int64)
    n_cols = 0
    for lab in range(named.shape[1]):
        if lab == empty:
            continue
        for part in range(named.shape[0]):
            if named[part, lab]:
                column[lab] = n_cols
                class_of[n_cols] = lab
                n_cols += 1
                break
    return column, class_of, n_cols


@nb.njit(cache=True, inline="always")
def _bit(col: np.int64) -> np.uint64:
    """Column ``col``'s bit in its word ``col >> 6`` of a cell's ``seen`` bits (its sum has started)."""
    return np.uint64(1) << np.uint64(col & 63)


@nb.njit(cache=True, inline="always")
def _sum_part(part: int, keys, valid, table_keys, table_cells, mask: int, sem_labels, sem_probs, column, older, count,
              sums, seen, deferred, n_deferred, set_size) -> None:
    """Pass 2 for chunk ``part`` of the points (see the module docstring); its points of the cells first met in an
    earlier chunk (``j < older[part]``) go to ``deferred`` from the chunk's start on, their number to
    ``n_deferred[part]``.
    ``set_size.ndim`` is k (``RUN_K + 1`` for any larger k), so each k compiles its own loop, free of tests of k."""
    lo, hi = _chunk(part, n_deferred.shape[0], valid.shape[0])
    k = set_size.ndim
    runs = k <= RUN_K
    key, j = np.int64(-1), np.int64(-1)  # the last key looked up and its cell
    run = -1  # the cell of the open run, -1 when none
    n_run = 0
    l0 = l1 = l2 = l3 = np.int64(-1)  # the run's labels, their columns and sums
    c0 = c1 = c2 = c3 = np.int64(-1)
    a0 = a1 = a2 = a3 = np.int64(-1)
    s0 = s1 = s2 = s3 = 0.0
    for i in range(lo, hi):
        if not valid[i]:
            continue
        p = pack_key(keys[i, 0], keys[i, 1], keys[i, 2])
        if runs:
            a0 = np.int64(sem_labels[i, 0])
            a1 = np.int64(sem_labels[i, 1]) if k > 1 else np.int64(-1)
            a2 = np.int64(sem_labels[i, 2]) if k > 2 else np.int64(-1)
            a3 = np.int64(sem_labels[i, 3]) if k > 3 else np.int64(-1)
            if run >= 0 and p == key and a0 == l0 and a1 == l1 and a2 == l2 and a3 == l3:
                n_run += 1
                s0 += np.float64(sem_probs[i, 0])
                if k > 1:
                    s1 += np.float64(sem_probs[i, 1])
                if k > 2:
                    s2 += np.float64(sem_probs[i, 2])
                if k > 3:
                    s3 += np.float64(sem_probs[i, 3])
                continue
            if run >= 0:  # the run ends: its count and sums into its cell's row
                count[run] += n_run
                if c0 >= 0:
                    sums[run, c0] = s0
                if c1 >= 0:
                    sums[run, c1] = s1
                if c2 >= 0:
                    sums[run, c2] = s2
                if c3 >= 0:
                    sums[run, c3] = s3
                run = -1
        if p != key:
            key, j = p, np.int64(-1)
            h = _slot(p, mask)
            while table_keys[h] != -1:
                if table_keys[h] == p:
                    j = np.int64(table_cells[h])
                    break
                h = (h + 1) & mask
        if j < 0:
            continue
        if j < older[part]:  # an earlier chunk's cell: added after that chunk
            deferred[lo + n_deferred[part]] = i
            n_deferred[part] += 1
            continue
        if runs:
            c0 = np.int64(column[a0])
            c1 = np.int64(column[a1]) if k > 1 else np.int64(-1)
            c2 = np.int64(column[a2]) if k > 2 else np.int64(-1)
            c3 = np.int64(column[a3]) if k > 3 else np.int64(-1)
            if not ((c0 >= 0 and c0 in (c1, c2, c3)) or (c1 >= 0 and c1 in (c2, c3))
                    or (c2 >= 0 and c2 == c3)):  # a set naming a class twice is added point by point below
                run, n_run = j, 1
                l0, l1, l2, l3 = a0, a1, a2, a3
                s0 = np.float64(sem_probs[i, 0])  # an unused sum (no column) adds up unread
                if c0 >= 0:
                    s0 = (sums[j, c0] if seen[j, c0 >> 6] & _bit(c0) else 0.0) + s0
                    seen[j, c0 >> 6] |= _bit(c0)
                if k > 1:
                    s1 = np.float64(sem_probs[i, 1])
                    if c1 >= 0:
                        s1 = (sums[j, c1] if seen[j, c1 >> 6] & _bit(c1) else 0.0) + s1
                        seen[j, c1 >> 6] |= _bit(c1)
                if k > 2:
                    s2 = np.float64(sem_probs[i, 2])
                    if c2 >= 0:
                        s2 = (sums[j, c2] if seen[j, c2 >> 6] & _bit(c2) else 0.0) + s2
                        seen[j, c2 >> 6] |= _bit(c2)
                if k > 3:
                    s3 = np.float64(sem_probs[i, 3])
                    if c3 >= 0:
                        s3 = (sums[j, c3] if seen[j, c3 >> 6] & _bit(c3) else 0.0) + s3
                        seen[j, c3 >> 6] |= _bit(c3)
                continue
        count[j] += 1
        for c in range(sem_labels.shape[1]):
            col = np.int64(column[sem_labels[i, c]])
            if col >= 0:
                sums[j, col] = (sums[j, col] if seen[j, col >> 6] & _bit(col) else 0.0) + np.float64(sem_probs[i, c])
                seen[j, col >> 6] |= _bit(col)
    if run >= 0:
        count[run] += n_run
        if c0 >= 0:
            sums[run, c0] = s0
        if c1 >= 0:
            sums[run, c1] = s1
        if c2 >= 0:
            sums[run, c2] = s2
        if c3 >= 0:
            sums[run, c3] = s3


@nb.njit(cache=True, parallel=True, nogil=True)
def _sum_parallel(keys, valid, table_keys, table_cells, mask, sem_labels, sem_probs, column, older, count, sums,
                  seen, deferred, n_deferred, set_size) -> None:
    for part in nb.prange(n_deferred.shape[0]):
        _sum_part(part, keys, valid, table_keys, table_cells, mask, sem_labels, sem_probs, column, older, count,
                  sums, seen, deferred, n_deferred, set_size)


@nb.njit(cache=True, nogil=True)
def _sum_serial(keys, valid, table_keys, table_cells, mask, sem_labels, sem_probs, column, older, count, sums,
                seen, deferred, n_deferred, set_size) -> None:
    _sum_part(0, keys, valid, table_keys, table_cells, mask, sem_labels, sem_probs, column, older, count, sums,
              seen, deferred, n_deferred, set_size)


@nb.njit(cache=True, nogil=True)
def _add_deferred(keys, table_keys, table_cells, mask: int, sem_labels, sem_probs, column, count, sums, seen,
                  deferred, n_deferred) -> None:
    """The points ``_sum_part`` left for later (few: those of cells that straddle two chunks), chunk by chunk, in
    input order, added point by point."""
    n, parts = keys.shape[0], n_deferred.shape[0]
    for part in range(parts):
        lo = _chunk(part, parts, n)[0]
        for t in range(lo, lo + n_deferred[part]):
            i = deferred[t]
            p = pack_key(keys[i, 0], keys[i, 1], keys[i, 2])
            h = _slot(p, mask)
            while table_keys[h] != p:
                h = (h + 1) & mask
            j = table_cells[h]
            count[j] += 1
            for c in range(sem_labels.shape[1]):
                col = np.int64(column[sem_labels[i, c]])
                if col >= 0:
                    sums[j, col] = ((sums[j, col] if seen[j, col >> 6] & _bit(col) else 0.0)
                                    + np.float64(sem_probs[i, c]))
                    seen[j, col >> 6] |= _bit(col)


@nb.njit(cache=True, inline="always")
def _largest_part(part: int, parts: int, sem_labels, sem_probs, first, count, sums, seen, class_of, out_labels,
                  out_probs) -> None:
    """Pass 3 for chunk ``part`` of the cells: the k largest sums (ties: the lower class, met first, by insertion
    into a list of k) divided by the cell's points; a cell of one point its point's set, as given."""
    m, k = count.shape[0], sem_labels.shape[1]
    chunk = (m + parts - 1) // parts
    best = np.empty(k, np.float64)
    for j in range(part * chunk, min(m, (part + 1) * chunk)):
        if count[j] == 1:
            for c in range(k):
                out_labels[j, c] = sem_labels[first[j], c]
                out_probs[j, c] = sem_probs[first[j], c]
            continue
        filled = 0
        for w in range(seen.shape[1] if count[j] > 1 else 0):
            bits, col = seen[j, w], w * 64
            while bits:  # the started sums, in column order
                if bits & np.uint64(1):
                    v = sums[j, col]
                    pos = filled
                    while pos > 0 and v > best[pos - 1]:
                        pos -= 1
                    if pos < k:
                        for t in range(min(filled, k - 1), pos, -1):
                            best[t] = best[t - 1]
                            out_labels[j, t] = out_labels[j, t - 1]
                        best[pos] = v
                        out_labels[j, pos] = class_of[col]
                        filled = min(filled + 1, k)
                bits >>= np.uint64(1)
                col += 1
        for c in range(filled):
            out_probs[j, c] = np.float32(best[c] / count[j])


@nb.njit(cache=True, parallel=True, nogil=True)
def _largest_parallel(sem_labels, sem_probs, first, count, sums, seen, class_of, out_labels, out_probs,
                      parts) -> None:
    for part in nb.prange(parts):
        _largest_part(part, parts, sem_labels, sem_probs, first, count, sums, seen, class_of, out_labels, out_probs)


@nb.njit(cache=True, nogil=True)
def _largest_serial(sem_labels, sem_probs, first, count, sums, seen, class_of, out_labels, out_probs,
                    parts) -> None:
    _largest_part(0, 1, sem_labels, sem_probs, first, count, sums, seen, class_of, out_labels, out_probs)


def compile_variants(k: int) -> None:
    """Compile (or load) the serial and parallel variants for sets of ``k`` on a tiny scan."""
    keys = np.array([[0, 0, 0], [1, 0, 0]], np.int32)
    labels = np.zeros((2, k), np.uint16)
    probs = np.full((2, k), 0.5, np.float32)
    for parts in (1, 2):
        _mean_sets(keys, np.ones(2, np.bool_), np.array([0, 1], np.int64), np.array([0, 1], np.int64), labels,
                   probs, LABEL_RANGE, 0xFFFF, parts)
