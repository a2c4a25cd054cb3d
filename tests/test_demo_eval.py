"""The demo chain (simulate, oracle segmentation, map, evaluate) and the evaluation maths it reports."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
from semmap.datasets.simulated import SimulatedDataset, scene_of_folder
from semmap.eval.semantic import confusion, match_voxels, scores
from semmap.perception.oracle import OracleSegmenter
from semmap.pipeline import Pipeline
from semmap.sim.ground_truth import gt_voxels
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import CameraIntrinsics

SMALL = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)


def test_confusion_and_iou_follow_the_definitions():
    gt = np.array([1, 1, 2, 2, 2, 0])
    pred = np.array([1, 2, 2, 2, 1, 1])
    conf = confusion(pred, gt, 3)
    assert conf.tolist() == [[0, 0, 0], [0, 1, 1], [0, 1, 2]]  # gt 0 ignored
    s = scores(conf)
    assert s.iou[1] == pytest.approx(1 / 3) and s.iou[2] == pytest.approx(2 / 4)
    assert s.miou == pytest.approx((1 / 3 + 1 / 2) / 2)
    assert s.accuracy == pytest.approx(3 / 5) and s.mpa == pytest.approx((1 / 2 + 2 / 3) / 2)
    assert np.isnan(s.iou[0])


def test_voxel_matching_uses_exact_keys_then_neighbours():
    gt_keys = np.array([[10, 10, 10], [20, 20, 20]])
    gt_labels = np.array([3, 4])
    map_keys = np.array([[10, 10, 10], [21, 20, 20], [40, 40, 40]])
    m = match_voxels(map_keys, np.array([3, 5, 6]), gt_keys, gt_labels)
    assert m.gt.tolist() == [3, 4] and m.pred.tolist() == [3, 5]
    assert m.precision == pytest.approx(2 / 3) and m.coverage == 1.0


@pytest.fixture(scope="module")
def short_demo(tmp_path_factory):
    scene = generate_scene(0, "office", "medium")
    poses = make_trajectory(scene, "loop", 45, seed=0)
    dataset = SimulatedDataset(scene, poses, intrinsics=SMALL, name="sim-test")
    out = tmp_path_factory.mktemp("demo")
    config = RunConfig(input=InputConfig(dataset=Path("sim-test")), mapping=MappingConfig(resolution=0.08),
                       semantics=SemanticsConfig(source="oracle"), output=OutputConfig(out=out, cloud=True))

    def ground_truth(res):
        gt = gt_voxels(scene, res)
        return gt.keys, gt.class_ids

    return Pipeline(config, segmenter=OracleSegmenter(dataset.label_set), dataset=dataset,
                    ground_truth=ground_truth).run()


@pytest.mark.slow
def test_demo_reports_3d_accuracy_above_single_frame_segmentation(short_demo):
    r = short_demo.report
    for key in ("miou_3d", "oracle_miou_2d", "per_class_iou_3d", "geometric_precision_3d", "gt_coverage_3d"):
        assert key in r, key
    assert r["miou_3d"] > r["oracle_miou_2d"] + 0.03, "multi-view fusion must beat single frames"
    assert r["geometric_precision_3d"] > 0.9
    assert 0.6 < r["oracle_pixel_accuracy_2d"] < 0.9  # the cnn-like oracle is ~75 % accurate
    md = (short_demo.out_dir / "report.md").read_text()
    assert "mIoU" in md and "OctoMap .bt" in md and "dense coloured point cloud" in md
    assert json.loads((short_demo.out_dir / "report.json").read_text())["miou_3d"] == r["miou_3d"]


@pytest.mark.slow
def test_a_simulated_folder_regenerates_its_scene_for_ground_truth(tmp_path):
    from semmap.sim.export import simulate_sequence

    root = simulate_sequence(tmp_path / "seq", frames=2, size="small", intrinsics=SMALL)
    scene = scene_of_folder(root)
    assert scene is not None
    assert scene.n_triangles == json.loads((root / "scene.json").read_text())["n_triangles"]
    info = json.loads((root / "scene.json").read_text())
    info["n_triangles"] += 1
    (root / "scene.json").write_text(json.dumps(info))
    assert scene_of_folder(root) is None
