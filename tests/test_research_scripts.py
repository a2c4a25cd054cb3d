"""The math behind the diagnostic scripts whose findings docs/EXPERIMENTS.md quotes: the camera-offset fit and
pose averaging of ``scripts/research/tracker_agreement.py``, the RPE of ``scripts/research/slam_check.py``, and the
pose-list reading, colour-camera move and rotation comparison of
``scripts/research/seven_scenes_sfm_reference.py``; the per-voxel selectors and edge masks of
``scripts/research/fusion_loss_check.py``; the revisit count and drift placement of
``scripts/research/walk_drift_check.py``."""

from __future__ import annotations

import json
import sys

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from script_modules import load_script
from semmap.errors import FormatError
from semmap.types import Trajectory


def _script(name: str):
    return load_script(f"scripts/research/{name}.py")


@pytest.fixture(scope="module")
def agreement():
    return _script("tracker_agreement")


def _walk(n: int = 120, seed: int = 0) -> Trajectory:
    """A camera wandering through a room, turning by up to about 40 degrees about every axis."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, n)
    poses = np.tile(np.eye(4), (n, 1, 1))
    angles = np.stack([0.4 * np.sin(t + rng.uniform(0, 6)), 0.7 * np.sin(2 * t), 0.3 * np.cos(3 * t)], axis=1)
    poses[:, :3, :3] = Rotation.from_rotvec(angles).as_matrix()
    poses[:, :3, 3] = np.stack([np.cos(t), np.sin(t), 0.2 * np.sin(4 * t)], axis=1)
    return Trajectory(np.arange(n) / 30.0, poses, tuple(f"f{i}" for i in range(n)))


def _with_camera_offset(reference: Trajectory, offset: np.ndarray, seed: int = 1) -> Trajectory:
    """The reference moved rigidly into another world frame, each pose describing a point ``offset`` (camera
    frame) away from the reference's: its positions plus R_i @ offset are the reference's, moved."""
    world = np.eye(4)
    world[:3, :3] = Rotation.from_rotvec(np.random.default_rng(seed).normal(size=3)).as_matrix()
    world[:3, 3] = [0.5, -2.0, 1.0]
    shift = np.eye(4)
    shift[:3, 3] = -offset
    return Trajectory(reference.timestamps, world @ reference.poses @ shift, reference.names)


def test_camera_offset_fit_recovers_a_known_offset(agreement) -> None:
    gt = _walk()
    offset = np.array([0.03, 0.10, -0.05])
    moved = _with_camera_offset(gt, offset)
    assert agreement.ate_cm(gt, moved) > 1.0  # the offset shows as trajectory error without the fit
    [ate], fitted = agreement.ates_with_camera_offset(gt, [moved])
    assert ate < 1e-3
    np.testing.assert_allclose(fitted, 100 * offset, atol=1e-3)


def test_one_offset_for_all_cannot_fit_two_different_offsets(agreement) -> None:
    gt = _walk()
    a, b = _with_camera_offset(gt, np.array([0.0, 0.1, 0.0])), _with_camera_offset(gt, np.array([0.0, -0.1, 0.0]), 2)
    ates, fitted = agreement.ates_with_camera_offset(gt, [a, b])
    assert min(ates) > 1.0
    np.testing.assert_allclose(fitted, 0.0, atol=0.5)  # halfway between +10 and -10 cm


def test_a_true_offset_carries_over_between_halves(agreement) -> None:
    gt = _walk()
    moved = _with_camera_offset(gt, np.array([0.02, 0.08, -0.04]))
    for without, with_offset in agreement.offset_transfer(gt, moved):
        assert without > 1.0
        assert with_offset < 0.01


def test_chordal_mean_lies_between_symmetric_perturbations(agreement) -> None:
    gt = _walk(40)
    nudge = np.eye(4)
    nudge[:3, :3] = Rotation.from_rotvec([0.0, 0.05, 0.0]).as_matrix()
    nudge[:3, 3] = [0.02, 0.0, 0.0]
    ahead = Trajectory(gt.timestamps, gt.poses @ nudge, gt.names)
    behind = Trajectory(gt.timestamps, gt.poses @ np.linalg.inv(nudge), gt.names)
    mean = agreement.chordal_mean([ahead, behind])
    np.testing.assert_allclose(mean.poses[:, :3, :3], gt.poses[:, :3, :3], atol=1e-12)
    # translations average exactly; the two nudges' translations differ only by the rotation they go with
    assert np.abs(mean.poses[:, :3, 3] - gt.poses[:, :3, 3]).max() < 1e-3


def test_slam_check_rpe_reads_slightly_non_orthonormal_ground_truth_as_still() -> None:
    rpe = _script("slam_check").rpe
    gt = _walk(60).poses
    est = gt.copy()
    shrink = 1 - 3e-4 * np.random.default_rng(3).uniform(size=(len(gt), 1, 3))
    gt[:, :3, :3] *= shrink  # 7-Scenes' rotations are off orthonormal by up to this much
    trans, angle_deg = rpe(est, gt, 1)
    assert trans < 1e-3
    assert angle_deg < 0.01  # arccos of the trace reads 0.43 degrees here
    n = len(est)
    spin = Rotation.from_rotvec(np.outer(0.01 * np.arange(n), [0, 0, 1])).as_matrix()
    turned = est.copy()
    turned[:, :3, :3] = spin @ est[:, :3, :3]  # the world turning under the camera by 0.01 rad a frame
    turned[:, :3, 3] = np.einsum("nij,nj->ni", spin, est[:, :3, 3])
    _, angle_deg = rpe(turned, gt, 5)
    assert angle_deg == pytest.approx(np.degrees(0.05), rel=1e-3)


@pytest.fixture(scope="module")
def sfm_reference():
    return _script("seven_scenes_sfm_reference")


def _pose_list_line(sequence: str, frame: int, T_world_cam: np.ndarray) -> str:
    """One line of a COLMAP-convention pose list (world-to-camera, quaternion w first), as Brachmann et al. store
    their 7-Scenes pseudo ground truth."""
    R, t = T_world_cam[:3, :3].T, -T_world_cam[:3, :3].T @ T_world_cam[:3, 3]
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return f"{sequence}/frame-{frame:06d}.color.png {w} {x} {y} {z} {t[0]} {t[1]} {t[2]} 525.505"


def test_sfm_reference_reads_a_pose_list_back_to_the_colour_cameras_trajectory(sfm_reference, tmp_path) -> None:
    depth = _walk(90)
    colour = sfm_reference.to_color_camera(depth)
    # the colour camera sits beside the depth camera: positions move by R_i @ (-t), as the calibration says
    offset = -np.asarray(sfm_reference.SEVEN_SCENES_COLOR_CAMERA.t_color_depth)
    np.testing.assert_allclose(colour.positions, depth.positions + depth.poses[:, :3, :3] @ offset, atol=1e-12)
    world = np.eye(4)
    world[:3, :3] = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    world[:3, 3] = [1.0, 2.0, -0.5]
    lines = [_pose_list_line("seq-02", 5, np.eye(4))]  # another sequence's line is skipped
    lines += [_pose_list_line("seq-01", i, world @ T) for i, T in enumerate(colour.poses) if i != 7]  # frame 7 lost
    path = tmp_path / "redkitchen_train.txt"
    path.write_text("\n".join(lines[::-1]) + "\n")  # the published files are not in frame order
    sfm = sfm_reference.as_trajectory(sfm_reference.read_pose_list(path, "seq-01"))
    assert len(sfm) == 89 and sfm.names[7] == "frame-000008"
    sfm, estimate = sfm_reference.common_frames(sfm, colour)
    assert len(estimate) == 89
    np.testing.assert_allclose(sfm.poses, world @ estimate.poses, atol=1e-9)
    assert sfm_reference.rotation_disagreement_deg(sfm, estimate, 5) < 1e-6
    scores = sfm_reference.evaluate_trajectory(sfm, estimate)
    assert scores["ate_rmse_m"] < 1e-9
    assert scores["sim3_scale"] == pytest.approx(1.0)


def test_sfm_reference_rotation_disagreement_measures_a_known_drift(sfm_reference) -> None:
    ref = _walk(60)
    spin = Rotation.from_rotvec(np.outer(0.002 * np.arange(60), [0, 1, 0])).as_matrix()
    drifting = ref.poses.copy()
    drifting[:, :3, :3] = spin @ ref.poses[:, :3, :3]  # a heading drifting by 0.002 rad a frame
    est = Trajectory(ref.timestamps, drifting, ref.names)
    assert sfm_reference.rotation_disagreement_deg(ref, est, 5) == pytest.approx(np.degrees(0.01), rel=0.02)
    assert sfm_reference.rotation_disagreement_deg(ref, est, 30) == pytest.approx(np.degrees(0.06), rel=0.02)


@pytest.mark.parametrize(("line", "message"), [
    ("seq-01/frame-000001.color.png 0.9 0.0 0.0 0.0 1 2 3 525", "quaternion norm"),
    ("seq-01/frame-000001.color.png 1 0 0 0 1 2", "expected 'name qw qx qy qz tx ty tz"),
    ("seq-01/frame-000001.color.png 1 0 0 zero 1 2 3", "not all numbers"),
])
def test_sfm_reference_names_the_file_and_line_of_a_bad_pose(sfm_reference, tmp_path, line, message) -> None:
    path = tmp_path / "pgt.txt"
    path.write_text("seq-01/frame-000000.color.png 1 0 0 0 0 0 0 525\n" + line + "\n")
    with pytest.raises(FormatError, match=f"pgt.txt:2: .*{message}"):
        sfm_reference.read_pose_list(path, "seq-01")


def test_sfm_reference_says_when_the_sequence_is_not_in_the_file(sfm_reference, tmp_path) -> None:
    path = tmp_path / "pgt.txt"
    path.write_text("seq-03/frame-000000.color.png 1 0 0 0 0 0 0 525\n")
    with pytest.raises(FormatError, match="no poses of sequence 'seq-01'"):
        sfm_reference.read_pose_list(path, "seq-01")


def test_sfm_reference_says_when_the_file_cannot_be_read(sfm_reference, tmp_path) -> None:
    with pytest.raises(FormatError, match=r"missing\.txt: cannot read the pose list"):
        sfm_reference.read_pose_list(tmp_path / "missing.txt", "seq-01")


@pytest.fixture(scope="module")
def loss_check():
    return _script("fusion_loss_check")


def test_max_keeps_the_most_confident_view_where_the_plurality_is_wrong(loss_check) -> None:
    # one voxel seen 3 times: twice class 2 (confidence 0.6), once class 5 (0.9); another voxel: class 7 once
    inv = np.array([0, 0, 0, 1])
    labels = np.array([[2, 5, 0], [2, 5, 0], [5, 2, 0], [7, 0, 0]])
    probs = np.array([[0.6, 0.3, 0.0], [0.6, 0.3, 0.0], [0.9, 0.05, 0.0], [0.8, 0.0, 0.0]])
    assert list(loss_check.plurality(inv, labels[:, 0], 2)) == [2, 7]
    assert list(loss_check.most_confident(inv, labels[:, 0], probs[:, 0], 2)) == [5, 7]
    # the summed probabilities: class 2 has 0.6 + 0.6 + 0.05, class 5 has 0.3 + 0.3 + 0.9
    assert list(loss_check.summed(inv, labels, probs, 2, log=False)) == [5, 7]
    # weights can silence the confident view
    w = np.array([1.0, 1.0, 0.01, 1.0])
    assert list(loss_check.summed(inv, labels, probs, 2, log=True, weights=w)) == [2, 7]


def test_auroc_of_a_perfect_and_a_useless_score(loss_check) -> None:
    right = np.array([False, False, True, True])
    assert loss_check.auroc(np.array([0.1, 0.2, 0.8, 0.9]), right) == 1.0
    assert loss_check.auroc(np.array([0.9, 0.8, 0.2, 0.1]), right) == 0.0


def test_edges_mark_pixels_near_a_class_border_or_a_depth_jump(loss_check) -> None:
    labels = np.zeros((8, 8), np.int32)
    labels[:, 4:] = 3
    near = loss_check.near_label_boundary(labels, r=1)
    assert near[:, 3:5].all() and not near[:, :2].any() and not near[:, 6:].any()
    depth = np.full((8, 8), 2.0)
    depth[:, 4:] = 2.5  # a 0.5 m step; a slope of 1 cm per pixel is not an edge
    depth += 0.01 * np.arange(8)[:, None]
    edge = loss_check.near_depth_edge(depth, r=1)
    assert edge[:, 3:5].all() and not edge[:, :2].any() and not edge[:, 6:].any()


def test_counterfactual_gain_is_zero_when_the_map_takes_every_network_label(loss_check) -> None:
    gt = np.array([1, 1, 2, 2])
    net = np.array([1, 2, 2, 2])
    mapped = np.array([1, 1, 2, 2])  # right everywhere
    assert loss_check.counterfactual_gain(gt, net, mapped, np.ones(4, bool)) == 0.0
    assert loss_check.counterfactual_gain(gt, net, mapped, np.zeros(4, bool)) > 0.4


def test_segmentation_grid_agreement_pairs_the_same_things_of_two_label_sets():
    """``scripts/segmentation_grid.py``: PASCAL's chair / diningtable against semmap's chair / table+desk."""
    grid = load_script("scripts/segmentation_grid.py")
    voc = ("background", "chair", "diningtable")
    ours = ("unknown", "wall", "table", "chair", "desk")
    a = np.array([[1, 1, 2, 2, 0]])  # chair chair diningtable diningtable background
    b = np.array([[3, 1, 2, 4, 3]])  # chair wall table desk chair
    assert grid.pairs(voc, ours) == ["chair ~ chair", "diningtable ~ table/desk"]
    rows = grid.agreement(a, b, voc, ours)  # intersection, pixels of a, pixels of b
    assert rows.tolist() == [[1, 2, 2], [2, 2, 2]]


@pytest.mark.slow
def test_segmentation_grid_draws_segmenters_that_need_depth_beside_networks(seven_scenes, tmp_path, monkeypatch):
    """``--segmenter structure --compare fcn+structure``: segmenters that need depth see the frame as semmap run
    gives it, and the picture has a column each (the colour view and two segmenters, one row per frame)."""
    grid = load_script("scripts/segmentation_grid.py")
    out = tmp_path / "grid.png"
    monkeypatch.setattr(sys, "argv", ["segmentation_grid.py", "--dataset", str(seven_scenes), "--frames", "0",
                                      "--segmenter", "structure", "--compare", "fcn+structure", "--out", str(out)])
    grid.main()
    picture = cv2.imread(str(out))
    assert picture.shape[1] == 3 * round(picture.shape[0] * 4 / 3)  # one 4:3 row: the view and two segmenters
    summary = json.loads(out.with_suffix(".json").read_text())
    assert [s["segmenter"] for s in summary["segmenters"]][:2] == ["structure", "fcn+structure"]


def test_temperature_check_recovers_the_temperature_that_made_the_probabilities() -> None:
    """``temperature_check.py`` fits T from a segmenter's probabilities at T = 1: labels drawn from
    softmax(logits / 2) while the segmenter reports softmax(logits) give T near 2."""
    check = _script("temperature_check")
    rng = np.random.default_rng(0)
    logits = rng.normal(0.0, 3.0, (64, 64, 6))
    logits[..., 0] = -50.0  # class 0 is void: never predicted, never a label
    true = np.exp(logits / 2.0)
    true /= true.sum(axis=2, keepdims=True)
    labels = (true.cumsum(axis=2) > rng.random((64, 64, 1))).argmax(axis=2)

    class Segmenter:
        uses_depth = False
        temperature = 0.5

        def probabilities(self, rgb, depth):
            p = np.exp(logits / self.temperature)
            return p / p.sum(axis=2, keepdims=True)

    class Frame:
        rgb, depth = None, None

    frame = Frame()
    frame.labels = labels
    seg = Segmenter()
    t = check.fitted_temperature(seg, [frame], void=0, step=1)
    assert seg.temperature == 1.0  # it reads the probabilities uncalibrated
    assert 1.8 < t < 2.2


def test_fusion_gaps_check_measures_the_crf_unary_gap_of_each_voxel() -> None:
    gaps = _script("fusion_gaps_check")

    class Fused:
        def class_probs(self) -> np.ndarray:  # gaps log 9 = 2.2 nats, 0, and the 1e-8 clip's 18.4
            return np.array([[0.9, 0.1, 0.0], [0.5, 0.5, 0.0], [1.0, 0.0, 0.0]], np.float32)

    share, median = gaps.margin_shares(Fused(), 2.0)
    assert share == pytest.approx(2 / 3) and median == pytest.approx(np.log(9.0), rel=1e-5)
    assert gaps.margin_shares(Fused(), 12.0)[0] == pytest.approx(1 / 3)


@pytest.mark.slow
def test_network_fit_check_scores_a_one_class_network_by_that_class_share(tmp_path) -> None:
    """``network_fit_check.py`` scores a folder as the trainer validates: a network calling every pixel class c
    gets the pixel accuracy of c's share of the labelled pixels, and IoU only for c."""
    import torch

    from semmap.sim.export import simulate_sequence
    from semmap.train.data import gather

    fit = _script("network_fit_check")
    assert fit.every_nth(7, 3).tolist() == [0, 3, 6]
    with pytest.raises(ValueError, match="--every"):
        fit.every_nth(7, 0)
    folder = tmp_path / "seq"
    simulate_sequence(folder, scene_seed=5, frames=2, image_size=(64, 48))
    ds = gather([folder], (64, 48))
    labels = ds.labels[ds.labels != 0]
    c = int(np.bincount(labels).argmax())

    class OneClass(torch.nn.Module):
        def forward_train(self, x, depth):
            out = torch.zeros(x.shape[0], len(ds.label_set), *x.shape[-2:])
            out[:, c] = 1.0
            return out, None

    class Net:
        input_size, label_set, model = (64, 48), ds.label_set, OneClass()

        class spec:  # noqa: N801  (stands in for a NetworkSpec)
            uses_depth = False

    row = fit.folder_scores(Net(), folder, 1)
    assert row["images"] == 2
    assert row["pixel_accuracy"] == pytest.approx(np.mean(labels == c), abs=1e-3)
    assert 0.0 < row["miou"] < row["pixel_accuracy"]


def _line(n: int, back: bool) -> np.ndarray:
    """(n, 4, 4) poses along x at 1 cm per frame looking along +z, turning back half-way when ``back``."""
    x = np.arange(n) * 0.01
    if back:
        x = np.where(np.arange(n) < n // 2, x, x[n // 2] - (np.arange(n) - n // 2) * 0.01)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = x
    return poses


def test_walk_drift_check_counts_revisits_and_places_drift_where_it_arose():
    drift = _script("walk_drift_check")
    assert drift.path_stats(_line(600, back=False))["revisit_share"] == 0.0
    there_and_back = drift.path_stats(_line(600, back=True))
    assert there_and_back["path_m"] == pytest.approx(5.99) and 0.3 < there_and_back["revisit_share"] < 0.5
    gt = _line(300, back=False)
    est = gt.copy()
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("y", 2.0, degrees=True).as_matrix()
    est[100:] = est[99] @ turn @ np.linalg.inv(gt[99]) @ gt[100:]  # a 2-degree error in the step 99 -> 100
    pos, rot = drift.anchored_drift(gt, est)
    assert np.allclose(rot[:100], 0.0) and np.allclose(rot[100:], 2.0)
    assert pos[99] == 0.0 and pos[-1] == pytest.approx(np.radians(2.0) * 2.0, rel=0.01)  # lever arm 2 m
    assert drift.relative_error(gt, est, 99, 100)[1] == pytest.approx(2.0)
    assert drift.stretches(rot, 30)[0][2] == pytest.approx(2.0)
    assert drift.aligned_errors(gt, gt + 0.0).max() < 1e-12
