"""semmap eval-map --gt-ply (issue 36, deliverable 6): a map scored at labelled ground-truth points as ConceptGraphs'
and Kimera's evaluations score maps (mIoU, frequency-weighted mIoU, mean class accuracy), from a PLY written in
ScanNet's *_vh_clean_2.labels.ply layout out of a simulated scene's ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from semmap.cli import app
from semmap.errors import ConfigError, FormatError
from semmap.eval.labelled_points import point_scores
from semmap.eval.semantic import confusion, scores
from semmap.io.labelled_ply import read_labelled_vertices
from semmap.io.map_files import save_map
from semmap.keys import keys_to_coords
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.types import EMPTY_LABEL, TopKProbs

RES = 0.05


def scannet_ply(path, points: np.ndarray, labels: np.ndarray, *, ascii: bool = False, order: str = "<") -> None:
    """Vertices as ScanNet writes them (x y z float, red green blue alpha uchar, label ushort), then faces."""
    props = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
             ("alpha", "u1"), ("label", "u2")]
    kind = {"f4": "float", "u1": "uchar", "u2": "ushort"}
    fmt = "ascii" if ascii else {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    header = ["ply", f"format {fmt} 1.0", "comment scene ground truth", f"element vertex {len(points)}",
              *(f"property {kind[t]} {n}" for n, t in props), "element face 1",
              "property list uchar int vertex_indices", "end_header"]
    rows = np.zeros(len(points), [(n, order + t) for n, t in props])
    rows["x"], rows["y"], rows["z"] = points.T
    rows["red"] = 200
    rows["label"] = labels
    if ascii:
        body = "".join(" ".join(str(v) for v in r) + "\n" for r in rows.tolist()) + "3 0 1 2\n"
        path.write_bytes(("\n".join(header) + "\n" + body).encode())
    else:
        face = np.array([3], np.uint8).tobytes() + np.array([0, 1, 2], order + "i4").tobytes()
        path.write_bytes(("\n".join(header) + "\n").encode() + rows.tobytes() + face)


@pytest.fixture(scope="module")
def truth():
    """Ground-truth surface points (5 cm voxel centres) of a small simulated office, with their classes."""
    from semmap.labels import INDOOR_LABELS
    from semmap.sim.ground_truth import gt_voxels
    from semmap.sim.scene import generate_scene

    gt = gt_voxels(generate_scene(0, "office", "small"), 0.05)
    return INDOOR_LABELS, keys_to_coords(gt.keys, 0.05), gt.class_ids.astype(np.int64)


def map_of(labels, points: np.ndarray, classes: np.ndarray) -> SemanticOctoMap:
    """An OctoMap of the points with their classes (one-hot sets), seen from above the room."""
    m = SemanticOctoMap(RES, label_set=labels)
    sem = np.full((len(points), 3), EMPTY_LABEL, np.uint16)
    sem[:, 0] = classes
    probs = np.zeros((len(points), 3), np.float32)
    probs[:, 0] = 0.9
    for _ in range(2):
        m.insert_points(points, points.mean(0) + np.array([0, 0, 1.0]), semantics=TopKProbs(sem, probs))
    return m


def test_scores_follow_the_benchmarks_definitions(truth):
    labels, points, classes = truth
    good = point_scores(map_of(labels, points, classes), points, classes)
    assert good["points_miou"] > 0.99 and good["points_mean_class_accuracy"] > 0.99
    assert good["gt_points"] == int((classes != 0).sum())
    # every wall voxel called floor: the wall class's IoU goes to 0, and f.w. mIoU falls by its weight
    wall, floor = labels.id_of("wall"), labels.id_of("floor")
    wrong = np.where(classes == wall, floor, classes)
    bad = point_scores(map_of(labels, points, wrong), points, classes)
    assert bad["points_per_class_iou"]["wall"] == 0.0
    assert bad["points_fw_miou"] < good["points_fw_miou"] - 0.2 and bad["points_miou"] < good["points_miou"]
    # by hand: the map holding exactly the truth's classes at the points
    pred = np.where(classes == wall, floor, classes)
    s = scores(confusion(pred[classes != 0], classes[classes != 0], len(labels)))
    share = s.support[~np.isnan(s.iou)] / s.support[~np.isnan(s.iou)].sum()
    assert s.fw_miou == pytest.approx(float((s.iou[~np.isnan(s.iou)] * share).sum()))


def test_points_outside_the_map_take_the_nearest_voxel(truth):
    from semmap.eval.labelled_points import classes_at_points

    labels, points, classes = truth
    seen = points[:, 0] < np.median(points[:, 0])  # the map saw half the room
    m = map_of(labels, points[seen], classes[seen])
    pred, dist = classes_at_points(m, points)
    assert (pred != EMPTY_LABEL).all() and (dist[seen] == 0).all() and (dist[~seen] > 0).mean() > 0.9
    s = point_scores(m, points, classes)
    assert 0.3 < s["points_beyond_a_voxel"] < 0.6 and s["points_accuracy"] < 0.9


def test_the_ply_reader_takes_scannet_layouts(tmp_path, truth):
    _, points, classes = truth
    sub = slice(0, 500)
    for name, kwargs in (("le.ply", {}), ("be.ply", {"order": ">"}), ("ascii.ply", {"ascii": True})):
        scannet_ply(tmp_path / name, points[sub], classes[sub], **kwargs)
        p, c = read_labelled_vertices(tmp_path / name)
        assert np.allclose(p, points[sub], atol=1e-5) and c.tolist() == classes[sub].tolist(), name
    with pytest.raises(FormatError, match="no 'semantic' property"):
        read_labelled_vertices(tmp_path / "le.ply", "semantic")
    (tmp_path / "cut.ply").write_bytes((tmp_path / "le.ply").read_bytes()[:-2000])
    with pytest.raises(FormatError, match="truncated"):
        read_labelled_vertices(tmp_path / "cut.ply")
    for name, text in (("neg.ply", "ply\nformat ascii 1.0\nelement vertex -3\nproperty float x\nend_header\n"),
                       ("odd.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n"),
                       ("no.ply", "not a ply at all\n")):
        (tmp_path / name).write_text(text)
        with pytest.raises(FormatError):
            read_labelled_vertices(tmp_path / name)


def test_eval_map_command_with_gt_ply(tmp_path, truth):
    labels, points, classes = truth
    save_map(tmp_path / "map.semmap", map_of(labels, points, classes))
    scannet_ply(tmp_path / "scene_vh_clean_2.labels.ply", points, classes)
    out = tmp_path / "scores.json"
    r = CliRunner().invoke(app, ["eval-map", str(tmp_path / "map.semmap"), "--gt-ply",
                                 str(tmp_path / "scene_vh_clean_2.labels.ply"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    s = json.loads(out.read_text())
    assert s["points_miou"] > 0.8 and {"points_fw_miou", "points_mean_class_accuracy"} <= set(s)
    bad = classes.copy()
    bad[0] = len(labels) + 3
    scannet_ply(tmp_path / "foreign.ply", points, bad)
    with pytest.raises(ConfigError, match="outside the map's label set"):
        point_scores(map_of(labels, points, classes), *read_labelled_vertices(tmp_path / "foreign.ply"))
    r = CliRunner().invoke(app, ["eval-map", str(tmp_path / "map.semmap")])
    assert r.exit_code != 0 and "--gt-ply" in str(r.exception)
