"""Real labelled frames (issue 45): a folder of still RGB-D frames with NYU-40 label PNGs, and ``semmap eval-seg
SEQ --segmenter NAME`` scoring any segmenter in NYU-40 over the classes both name."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from semmap.cli import app
from semmap.datasets import detect_format, open_dataset
from semmap.errors import DatasetError
from semmap.eval.real_frames import nyu40_of
from semmap.labels import INDOOR_LABELS, NYU40_NAMES, simulator_to_nyu40
from semmap.perception.voc import PASCAL_VOC
from semmap.sim.noise import KinectNoise
from semmap.sim.render import Renderer
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import heading_pose


@pytest.fixture(scope="module")
def still_frames(tmp_path_factory):
    """Four views of a simulated bedroom stored as NYU-style still frames: rgb/, depth/ (mm), labels/ (NYU-40)."""
    root = tmp_path_factory.mktemp("nyu") / "frames"
    for sub in ("rgb", "depth", "labels"):
        (root / sub).mkdir(parents=True)
    renderer = Renderer(generate_scene(4, "bedroom"), noise=KinectNoise(seed=2))
    room = renderer.scene.rooms[0]
    c = (room.bounds_min + room.bounds_max) / 2
    to_nyu = simulator_to_nyu40()
    for i, (yaw, pitch) in enumerate(((0, -25), (200, -25), (90, 15), (300, -5))):
        v = renderer.render(heading_pose((c[0], c[1], 1.5), np.radians(yaw), np.radians(pitch), 0.0))
        cv2.imwrite(str(root / "rgb" / f"{i:04d}.jpg"), cv2.cvtColor(v.rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(root / "depth" / f"{i:04d}.png"), np.round(v.depth * 1000).astype(np.uint16))
        cv2.imwrite(str(root / "labels" / f"{i:04d}.png"), to_nyu[v.labels].astype(np.uint16))
    k = renderer.intrinsics
    (root / "intrinsics.txt").write_text(f"{k.fx} {k.fy} {k.cx} {k.cy}\n")
    return root


@pytest.mark.slow
def test_a_folder_of_still_frames_reads_as_nyu40_frames(still_frames) -> None:
    assert detect_format(still_frames) == "stills"
    frames = list(open_dataset(still_frames))
    assert len(frames) == 4 and all(f.T_world_cam is None for f in frames)
    assert open_dataset(still_frames).label_set.names == NYU40_NAMES
    assert frames[0].depth.dtype == np.float32 and 0.5 < np.median(frames[0].depth[frames[0].depth > 0]) < 6
    assert frames[0].intrinsics.fx == pytest.approx(Renderer(generate_scene(4, "bedroom")).intrinsics.fx)


def test_still_frames_without_depth_are_refused_in_one_line(tmp_path) -> None:
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    cv2.imwrite(str(tmp_path / "rgb" / "a.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(DatasetError, match="no colour image in rgb/ has a depth image"):
        open_dataset(tmp_path)


def test_every_segmenters_classes_meet_in_nyu40() -> None:
    voc = dict(zip(PASCAL_VOC.names, (NYU40_NAMES[i] for i in nyu40_of(PASCAL_VOC)), strict=True))
    assert voc["chair"] == "chair" and voc["diningtable"] == "table" and voc["sofa"] == "sofa"
    assert voc["tvmonitor"] == "television" and voc["background"] == "unknown" and voc["cow"] == "unknown"
    ours = dict(zip(INDOOR_LABELS.names, (NYU40_NAMES[i] for i in nyu40_of(INDOOR_LABELS)), strict=True))
    assert ours["wall"] == "wall" and ours["ceiling"] == "ceiling" and ours["shelf"] == "shelves"
    assert list(nyu40_of(__import__("semmap.labels", fromlist=["nyu40_labels"]).nyu40_labels())) == list(range(41))


def test_eval_seg_scores_a_segmenter_over_the_classes_both_name(still_frames, tmp_path) -> None:
    out = tmp_path / "scores.json"
    r = CliRunner().invoke(app, ["eval-seg", str(still_frames), "--segmenter", "structure", "--out", str(out)])
    assert r.exit_code == 0, r.output
    scores = json.loads(out.read_text())
    assert set(scores["classes"]) == {"wall", "floor", "ceiling"}  # what structure can name, and the frames hold
    per = scores["per_class"]
    assert per["floor"]["iou"] > 0.85 and per["wall"]["iou"] > 0.6 and per["ceiling"]["iou"] > 0.8, per
    assert scores["miou"] == pytest.approx(np.mean([per[c]["iou"] for c in scores["classes"]]), abs=1e-3)
    conf = np.array(scores["confusion"])
    assert conf.shape == (41, 41) and conf[0].sum() == 0  # void pixels are never scored
    # every labelled pixel counts: the pixel accuracy is over all of them, furniture included (structure misses it)
    assert scores["pixel_accuracy"] < per["floor"]["iou"]


def test_catch_all_classes_are_never_what_a_segmenter_names(still_frames, tmp_path) -> None:
    """The simulator's networks send keyboards, cups, bottles and plants to otherprop: not a class they name."""
    from semmap.datasets import open_dataset
    from semmap.eval.real_frames import score_segmenter
    from semmap.perception.registry import make_segmenter

    seg = make_segmenter("oracle", label_set=open_dataset(still_frames).label_set)
    scores = score_segmenter(open_dataset(still_frames), seg)
    assert not {"otherprop", "otherfurniture", "otherstructure"} & set(scores.classes)
    assert {"wall", "floor", "bed"} <= set(scores.classes)


def test_eval_seg_without_ground_truth_or_segmenter_says_what_to_give(still_frames) -> None:
    from semmap.errors import ConfigError

    r = CliRunner().invoke(app, ["eval-seg", str(still_frames)])
    assert isinstance(r.exception, ConfigError)
    assert "GT_DIR" in str(r.exception) and "--segmenter" in str(r.exception)
