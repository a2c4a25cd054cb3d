"""The OctoMap's mean class evidence per cell (maps/_cell_evidence.py) against the slow reference, to the bit, on
one thread and on several."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from naive import EMPTY, cell_mean_reference
from semmap.keys import pack_keys
from semmap.maps import _cell_evidence as ce


def endpoint_cells(keys: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(packed key, first point) of every cell of the valid points, in the order of their first points."""
    idx = np.flatnonzero(valid)
    packed = pack_keys(keys[idx].astype(np.int64))
    _, first = np.unique(packed, return_index=True)
    first = np.sort(first)
    return packed[first], idx[first].astype(np.int64)


def assert_same_bits(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> None:
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1].view(np.int32), b[1].view(np.int32))


@st.composite
def scans(draw):
    """Points of a few cells with top-k sets: runs of equal cells and sets, repeated classes, empty slots,
    invalid points and points of no endpoint cell, few classes or many (ids up to 65534)."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n, k = draw(st.integers(0, 300)), draw(st.integers(1, 6))
    classes = draw(st.sampled_from([3, 21, 200, 65535]))
    keys = np.repeat(rng.integers(0, 3, (n, 3)), rng.integers(1, 6, n), axis=0)[:n].astype(np.int32)
    labels = np.repeat(rng.integers(0, min(classes, 40) + 2, (n, k)) * (1 if classes < 100 else 997 % classes),
                       rng.integers(1, 4, n), axis=0)[:n]
    labels = np.where(rng.random(labels.shape) < 0.15, EMPTY, labels % 65535).astype(np.uint16)
    probs = rng.choice(np.array([0.0, 0.1, 0.25, 0.3, 0.5, 0.7], np.float32), labels.shape)
    if draw(st.booleans()):  # many magnitudes: float64 sums round, so their order shows in the bits
        probs = (10.0 ** rng.uniform(-14, 0, labels.shape)).astype(np.float32)
    valid = rng.random(keys.shape[0]) < 0.9
    packed, first = endpoint_cells(keys, valid)
    keep = rng.random(packed.shape[0]) < 0.9  # some cells are no endpoint cell (beyond the scan's grid)
    return keys, valid, packed[keep], first[keep], labels, probs, classes


@settings(max_examples=150, deadline=None)
@given(scans(), st.integers(1, 3))
def test_mean_evidence_matches_the_gathered_reference_to_the_bit(scan, parts):
    keys, valid, packed, first, labels, probs, classes = scan
    expected = cell_mean_reference(keys, valid, packed, labels, probs, classes)
    assert_same_bits(ce._mean_sets(keys, valid, packed, first, labels, probs, classes, EMPTY, parts), expected)


def test_mean_evidence_is_the_same_on_any_number_of_threads():
    """A depth-image-like scan (rows of pixels crossing cells, sets changing at edges): the chunks' cells straddle
    the chunk borders, whose points are added after the chunk that met the cell first."""
    rng = np.random.default_rng(3)
    h, w = 60, 80
    v, u = np.mgrid[0:h, 0:w]
    keys = np.stack([u // 7, v // 5, (u + v) // 30], -1).reshape(-1, 3).astype(np.int32)
    top = ((u // 11 + v // 13) % 9 + 1).reshape(-1)
    labels = np.stack([top, top % 9 + 1, (top + 4) % 9 + 1], 1).astype(np.uint16)
    probs = (10.0 ** rng.uniform(-14, 0, labels.shape)).astype(np.float32)  # sums that round: order shows
    valid = rng.random(labels.shape[0]) < 0.95
    packed, first = endpoint_cells(keys, valid)
    expected = cell_mean_reference(keys, valid, packed, labels, probs, 10)
    for parts in (1, 2, 3, 7):
        assert_same_bits(ce._mean_sets(keys, valid, packed, first, labels, probs, 10, EMPTY, parts), expected)
    assert_same_bits(ce.cell_mean_sets(keys, valid, packed, first, labels, probs, 10, EMPTY, 2), expected)


def test_mean_evidence_adds_each_cells_points_in_input_order():
    """Four points of one class whose float64 sum rounds differently in another order (3·2^-55 + 3·2^-55 +
    2^-24 + 1 lands above the float32 tie at 1 + 2^-24, the reverse order on it): the mean is the ordered one's,
    whether the points form one run, alternate with other cells' or fall into two chunks."""
    tiny, half = np.float32(3 * 2.0**-55), np.float32(2.0**-24)
    order = np.array([tiny, tiny, half, 1.0], np.float32)
    ordered = np.float32((((0.0 + float(tiny)) + float(tiny)) + float(half) + 1.0) / 4)
    assert ordered != np.float32((((0.0 + 1.0) + float(half)) + float(tiny) + float(tiny)) / 4)
    for at in ([0, 1, 2, 3], [0, 2, 4, 6], [0, 97, 98, 99]):  # one run; other cells between; chunks apart
        n = at[-1] + 1
        keys = np.zeros((n, 3), np.int32)
        keys[:, 0] = np.arange(n) + 1
        keys[at, 0] = 0
        labels = np.full((n, 1), 2, np.uint16)
        probs = np.full((n, 1), 0.5, np.float32)
        probs[at, 0] = order
        valid = np.ones(n, np.bool_)
        packed, first = endpoint_cells(keys, valid)
        for parts in (1, 2, 3):
            out = ce._mean_sets(keys, valid, packed, first, labels, probs, 5, EMPTY, parts)
            assert out[1][0, 0] == ordered, (at, parts)
