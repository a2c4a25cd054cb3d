"""Issue 33: the CRF weighs a log-odds grid's evidence per view, not per pixel (``refine_map(per_view=True)``).

A voxel grid with ``bayes`` sums every pixel's log-probabilities; many pixels of one frame in one voxel made its
unaries so certain that the CRF's pairwise terms could never move them (the 5 cm grid's CRF gained 0.5 points
where the OctoMap's gained 4.7). ``points_per_view`` says how many measurements per view each voxel summed."""

from __future__ import annotations

import numpy as np

from semmap.fusion.crf import CrfParams, refine_map
from semmap.fusion.rules import FusionParams, FusionRule
from semmap.maps.point_map import SemanticPointMap
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.types import EMPTY_LABEL, LabelSet, Observation, TopKProbs

K = 4
PER_VOXEL = 40  # points per voxel and frame
FRAMES = 3


def patch_frames(bad: tuple[int, int] = (5, 5)) -> list[Observation]:
    """A 10 x 10 voxel floor patch (5 cm) of one colour, class 1 everywhere but class 2 in voxel ``bad``, each voxel
    hit by PER_VOXEL points a frame with confidence 0.7, for FRAMES frames."""
    rng = np.random.default_rng(0)
    ij = np.stack(np.meshgrid(np.arange(10), np.arange(10), indexing="ij"), -1).reshape(-1, 2)
    out = []
    for _ in range(FRAMES):
        cells = np.repeat(ij, PER_VOXEL, axis=0)
        xy = (cells + rng.uniform(0.1, 0.9, cells.shape)) * 0.05
        pts = np.column_stack([xy, np.full(len(xy), 0.025)]).astype(np.float32)
        labels = np.full((len(pts), 1), 1, np.uint16)
        labels[(cells == bad).all(1), 0] = 2
        colors = np.full((len(pts), 3), 120, np.uint8)
        out.append(Observation(pts, np.array([0.25, 0.25, 1.5]), colors,
                               TopKProbs(labels, np.full((len(pts), 1), 0.7, np.float32))))
    return out


def bad_voxel_label(m) -> int:
    c = m.cloud()
    at = np.argmin(np.linalg.norm(c.centers[:, :2] - [0.275, 0.275], axis=1))
    return int(c.labels[at])


def test_points_per_view_counts_a_log_odds_grids_pixels_per_frame_and_one_for_other_rules():
    grid = SemanticVoxelGrid(0.05, label_set=LabelSet.generic(K), fusion=FusionParams(FusionRule.BAYES))
    points = SemanticPointMap(0.05, label_set=LabelSet.generic(K), fusion=FusionParams(FusionRule.BAYES_PRIOR))
    topk = SemanticVoxelGrid(0.05, label_set=LabelSet.generic(K), fusion=FusionParams(FusionRule.TOPK, k=1))
    for obs in patch_frames():
        for m in (grid, points, topk):
            m.integrate(obs)
    assert np.allclose(grid.points_per_view(), PER_VOXEL) and len(grid.points_per_view()) == len(grid.cloud())
    assert np.allclose(points.points_per_view(), PER_VOXEL)
    assert np.allclose(topk.points_per_view(), 1.0)
    assert not hasattr(SemanticOctoMap(0.05, label_set=LabelSet.generic(K)), "points_per_view")  # one mean a view


def test_per_view_distributions_divide_the_log_odds_and_keep_the_argmax():
    grid = SemanticVoxelGrid(0.05, label_set=LabelSet.generic(K), fusion=FusionParams(FusionRule.BAYES))
    for obs in patch_frames():
        grid.integrate(obs)
    p, q = grid.class_probs(), grid.class_probs_per_view()
    assert np.allclose(q.sum(1), 1.0) and (q.argmax(1) == p.argmax(1)).all()
    # 3 views of 0.7 against 0.1 (the other classes share 0.3): log-odds 3 log 7, not 120 log 7
    assert np.allclose(np.log(q.max(1) / np.sort(q, 1)[:, -2]), FRAMES * np.log(7.0), rtol=1e-3)
    assert p.max(1).min() == 1.0  # the per-pixel sum: float32 certainty
    topk = SemanticVoxelGrid(0.05, label_set=LabelSet.generic(K), fusion=FusionParams(FusionRule.TOPK, k=1))
    topk.integrate(patch_frames()[0])
    assert np.array_equal(topk.class_probs_per_view(), topk.class_probs())


def test_the_crf_moves_a_grid_voxel_its_pixels_made_certain_only_when_it_weighs_views():
    results = {}
    for per_view in (False, True):
        m = SemanticVoxelGrid(0.05, label_set=LabelSet.generic(K), fusion=FusionParams(FusionRule.BAYES))
        for obs in patch_frames():
            m.integrate(obs)
        assert bad_voxel_label(m) == 2
        refine_map(m, CrfParams(), viewpoint=np.array([0.25, 0.25, 1.5]), per_view=per_view)
        results[per_view] = bad_voxel_label(m)
        assert (m.cloud().labels[m.cloud().labels != EMPTY_LABEL] <= 2).all()
    # 120 pixels at 0.7 against 0.1: 233 nats summed, beyond any pairwise term; 3 views: 5.8 nats, the neighbours win
    assert results == {False: 2, True: 1}
