"""The map family end to end: several maps in one run, the 3D dense CRF, per-map evaluation, `semmap info`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from helpers import make_room_frames, room_label_set, run_cli
from semmap.eval.semantic import cloud_keys_and_labels
from semmap.fusion.crf import CrfParams, refine_map
from semmap.geometry import backproject_world, pixel_normals
from semmap.io.tum_writer import write_tum_sequence
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.types import EMPTY_LABEL, CameraIntrinsics, LabelSet, Observation, TopKProbs, make_pose


@pytest.mark.slow
def test_run_builds_every_map_side_by_side_and_info_reads_every_file(tmp_path):
    seq, out = tmp_path / "room", tmp_path / "out"
    write_tum_sequence(seq, make_room_frames(8), label_set=room_label_set())
    r = run_cli("run", str(seq), "--out", str(out), "--resolution", "0.1", "--maps", "voxelgrid,octomap,points",
                "--point-resolution", "0.05", "--crf", "--crf-every", "2", "--top-k", "2")
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert list(report["maps"]) == ["voxelgrid", "octomap", "points"]
    assert report["occupied_voxels"] == report["maps"]["voxelgrid"]["occupied_voxels"]  # the first map is primary
    assert report["ms_per_frame"]["crf"] > 0  # refined every second keyframe too
    assert json.loads((out / "config.json").read_text())["semantics"]["k"] == 2
    for kind, files in (("voxelgrid", ("voxelgrid.semmap", "voxelgrid.ply")), ("octomap", ("map.ot", "map.bt")),
                        ("points", ("points.semmap", "points.ply"))):
        entry = report["maps"][kind]
        assert set(files) <= set(entry["files"]) and entry["crf"]["refined"] > 0
        for name in files:
            d = json.loads(run_cli("info", str(out / name)).stdout)
            assert d["resolution"] == pytest.approx(entry["resolution"]), name
    assert json.loads(run_cli("info", str(out / "voxelgrid.semmap")).stdout)["occupied_voxels"] == \
        report["maps"]["voxelgrid"]["occupied_voxels"]
    assert (out / "preview_points.png").stat().st_size > 0
    md = (out / "report.md").read_text()
    assert "voxelgrid" in md and "points" in md
    r = run_cli("run", str(seq), "--out", str(tmp_path / "o2"), "--maps", "octomap", "--fusion", "bayes")
    assert r.returncode == 0, r.stderr  # every rule runs on the OctoMap too
    d = json.loads(run_cli("info", str(tmp_path / "o2" / "map.semmap")).stdout)
    assert d["fusion"] == "bayes"
    assert d["occupied"] == json.loads((tmp_path / "o2" / "report.json").read_text())["occupied_voxels"] > 0
    assert (tmp_path / "o2" / "map.ot").stat().st_size > 0
    r = run_cli("run", str(seq), "--out", str(tmp_path / "o3"), "--maps", "octree")
    assert r.returncode == 1 and "octomap" in r.stderr and "Traceback" not in r.stderr


def test_crf_cleans_up_salt_and_pepper_labels_on_two_surfaces():
    rng = np.random.default_rng(0)
    K = 4
    g = np.stack(np.meshgrid(np.arange(0, 1.0, 0.05), np.arange(0, 1.0, 0.05)), -1).reshape(-1, 2)
    floor = np.column_stack([g, np.full(len(g), 0.025)])
    wall = np.column_stack([np.full(len(g), 1.025), g])
    pts = np.vstack([floor, wall]).astype(np.float32)
    truth = np.r_[np.full(len(g), 1), np.full(len(g), 2)]
    colors = np.where(truth[:, None] == 1, [200, 60, 60], [60, 60, 200]).astype(np.uint8)
    noisy = np.where(rng.random(len(pts)) < 0.35, rng.integers(1, K, len(pts)), truth)
    labels = np.full((len(pts), 1), EMPTY_LABEL, np.uint16)
    labels[:, 0] = noisy
    m = SemanticVoxelGrid(0.05, label_set=LabelSet.generic(K))
    m.integrate(Observation(pts, np.zeros(3), colors, TopKProbs(labels, np.full((len(pts), 1), 0.6, np.float32))))
    cloud = m.cloud()
    centre_truth = np.where(cloud.centers[:, 2] < 0.05, 1, 2)
    before = np.mean(cloud.labels == centre_truth)
    r = refine_map(m, CrfParams(), viewpoint=np.array([0.5, 0.5, 0.5]))
    after = np.mean(m.cloud().labels == centre_truth)
    assert r.refined == len(cloud) and r.changed > 0
    assert before < 0.85 and after > 0.95, (before, after)


def test_depth_image_normals_face_the_camera():
    cam = CameraIntrinsics(40, 30, 35.0, 35.0, 19.5, 14.5)
    v, u = np.mgrid[0:30, 0:40]
    normal = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])  # a tilted plane through (0, 0, 2)
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], -1)
    depth = ((normal @ [0.0, 0.0, 2.0]) / (rays @ normal)).astype(np.float32)
    R = make_pose(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [1.0, 2.0, 3.0])
    pts, pix = backproject_world(depth, cam, R)
    n = pixel_normals(depth, cam, R, pix)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert np.all((n * (pts - R[:3, 3])).sum(1) < 0)  # against the viewing rays
    assert np.allclose(n, R[:3, :3] @ normal, atol=1e-3)  # in the world frame


def test_a_fine_point_map_is_voxelised_by_majority_for_evaluation():
    centers = np.array([[0.01, 0.01, 0.01], [0.02, 0.01, 0.01], [0.03, 0.02, 0.01], [0.31, 0, 0]])
    keys, labels = cloud_keys_and_labels(centers, np.array([7, 4, 4, EMPTY_LABEL], np.uint16), 0.1)
    assert len(keys) == 2 and labels.tolist() == [4, int(EMPTY_LABEL)]
