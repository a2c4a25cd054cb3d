"""bench_networks.py shows the papers' two network claims with a paired bootstrap interval over the test frames
(issue 32), so that a difference can be told from noise."""

from __future__ import annotations

import numpy as np

from script_modules import load_script


def bench():
    return load_script("benchmarks/bench_networks.py")


def frame_confusions(rng, frames: int, k: int, accuracy: float) -> np.ndarray:
    """(F, K, K) confusions of a network right on ``accuracy`` of 1,000 pixels per frame (class 0 is void)."""
    out = np.zeros((frames, k, k), np.int64)
    for f in range(frames):
        gt = rng.integers(1, k, 1000)
        pred = np.where(rng.random(1000) < accuracy, gt, rng.integers(1, k, 1000))
        np.add.at(out[f], (gt, pred), 1)
    return out


def test_a_clear_gain_is_above_the_noise_and_a_tie_is_not():
    b = bench()
    rng = np.random.default_rng(0)
    nets = {"pspnet": frame_confusions(rng, 30, 6, 0.5), "cbam-pspnet": frame_confusions(rng, 30, 6, 0.7),
            "rgb-only": frame_confusions(rng, 30, 6, 0.5), "rgbd-net": frame_confusions(rng, 30, 6, 0.5)}
    intervals, claims = b.spread(nets)
    assert set(intervals) == set(nets)
    for lo, hi in intervals.values():
        assert 0.0 < lo < hi < 1.0
    by = {c["network"]: c for c in claims}
    cbam, rgbd = by["cbam-pspnet"], by["rgbd-net"]
    assert cbam["claim_met"] and cbam["above_noise"] and cbam["ci95_points"][0] > 5
    assert cbam["ci95_points"][0] <= cbam["miou_points"] <= cbam["ci95_points"][1]
    assert not rgbd["claim_met"] and not rgbd["above_noise"]
    assert rgbd["ci95_points"][0] < 0 < rgbd["ci95_points"][1]


def test_no_networks_no_claims():
    assert bench().spread({}) == ({}, [])
