"""A first contact without surprises, the reports and pictures half (issue 31, item 7): the run's summary and
reports name where the map's classes came from; the objects report states the rule the object map applies and
every listed object meets it; the localize report tells "reports convergence" from "on the true pose"; previews
and particle plots carry a legend of the classes they show; the trajectory plot is drawn in the preview's axes,
named; object labels never overprint; precomputed predictions take the dataset's class names; the scripts the
README sends a newcomer to (a test bag, a small training set) work."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from object_helpers import box_frames
from semmap.config import InputConfig, OutputConfig, RunConfig, SemanticsConfig, SemanticSource
from semmap.datasets import open_dataset
from semmap.eval import report_plots
from semmap.eval.report_md import render_report_md
from semmap.io.tum_writer import write_tum_sequence
from semmap.labels import INDOOR_LABELS
from semmap.localization.filter import FilterSettings, PoseEstimate
from semmap.localization.outputs import particles_figure, particles_png, report_dict
from semmap.localization.outputs import render_report_md as render_localize_md
from semmap.localization.prior import build_prior
from semmap.localization.run import InitMode, LocalizationResult, UpdateRecord
from semmap.maps.objects import ObjectMapParams
from semmap.run.prepare import GROUND_TRUTH_LABELS, NO_SEMANTICS, semantics_source
from semmap.types import LabelSet, MapCloud, Trajectory, make_pose
from semmap.viz import objects as viz_objects
from semmap.viz import preview

ROOT = Path(__file__).resolve().parents[1]
CHAIR, TABLE = INDOOR_LABELS.id_of("chair"), INDOOR_LABELS.id_of("table")
BOXES = [(np.array([-0.2, -0.8, 0.0]), np.array([0.2, -0.4, 0.8])),
         (np.array([0.8, 0.1, 0.0]), np.array([1.2, 0.5, 0.8])),
         (np.array([0.2, 0.9, 0.0]), np.array([1.2, 1.5, 0.75]))]


def _cli(*args: str):
    from semmap.cli import app

    return CliRunner().invoke(app, list(args))


def _words(text: str) -> str:
    """Text with every run of white space (Markdown line breaks, table wrapping) as one space."""
    return re.sub(r"\s+", " ", text)


@pytest.fixture(scope="module")
def boxes(tmp_path_factory) -> Path:
    """A TUM folder with ground-truth labels, instances and poses (three boxes seen along an arc)."""
    root = tmp_path_factory.mktemp("first-contact") / "boxes"
    write_tum_sequence(root, box_frames(BOXES, [CHAIR, CHAIR, TABLE], 12), label_set=INDOOR_LABELS)
    return root


@pytest.fixture(scope="module")
def box_run(boxes, tmp_path_factory):
    """``semmap run`` with no segmenter and oracle instances, in process: (output folder, printed summary)."""
    out = tmp_path_factory.mktemp("first-contact-run") / "out"
    result = _cli("run", str(boxes), "--out", str(out), "--resolution", "0.05", "--instances", "oracle",
                  "--instance-errors", "exact")
    assert result.exit_code == 0, result.output
    return out, result.output


# ---------------------------------------------------------------------------------------------- semantics source
@pytest.mark.slow
def test_a_run_without_a_segmenter_names_the_ground_truth_labels_in_summary_and_reports(box_run):
    out, printed = box_run
    report = json.loads((out / "report.json").read_text())
    assert report["semantics"] == GROUND_TRUTH_LABELS == "ground-truth labels from the dataset (not a segmenter)"
    assert f"Semantics: {GROUND_TRUTH_LABELS}" in (out / "report.md").read_text()
    row = next(line for line in printed.splitlines() if "semantics" in line)
    assert "ground-truth" in row


def _config(tmp_path: Path, **semantics) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=tmp_path / "seq"), semantics=SemanticsConfig(**semantics),
                     output=OutputConfig(out=tmp_path / "out"))


def test_the_semantics_source_names_the_segmenter_the_label_folder_or_none(tmp_path):
    labels = LabelSet.generic(4)
    assert semantics_source(_config(tmp_path), SimpleNamespace(name="pspnet"), labels) == "segmenter pspnet"
    oracle = semantics_source(_config(tmp_path, source=SemanticSource.ORACLE), SimpleNamespace(name="oracle"), labels)
    assert oracle.startswith("segmenter oracle") and "ground-truth" in oracle
    assert semantics_source(_config(tmp_path), None, labels, labels) == GROUND_TRUTH_LABELS
    no_labels = semantics_source(_config(tmp_path, source=SemanticSource.LABELS), None, labels, None)
    assert no_labels.startswith(NO_SEMANTICS) and "no label images" in no_labels  # asked for, none there
    assert semantics_source(_config(tmp_path, source=SemanticSource.NONE), None, labels, labels) == NO_SEMANTICS
    assert semantics_source(_config(tmp_path), None, None) == NO_SEMANTICS
    folder = RunConfig(input=InputConfig(dataset=tmp_path / "seq", labels=tmp_path / "mine"),
                       output=OutputConfig(out=tmp_path / "out"))
    assert semantics_source(folder, None, labels) == f"label images from {tmp_path / 'mine'} (not a segmenter)"


def _scored_report(**extra) -> dict:
    """The keys report.md reads from a run scored against ground truth (no objects, no plots)."""
    return {"dataset": "sim/tiny", "resolution": 0.05, "frames_used": 3, "frames_skipped": 0, "miou_3d": 0.9,
            "voxel_accuracy_3d": 0.94, "mpa_3d": 0.95, "geometric_precision_3d": 1.0, "gt_coverage_3d": 0.1,
            "gt_voxels": 1000, "per_class_iou_3d": {"wall": 0.9, "floor": 0.95}, "bytes_on_disk": {"map.ot": 10},
            "dense_point_cloud_bytes": 100, "bytes_per_voxel_in_memory": 30.0, "bytes_in_memory": 3000,
            "voxels": 100, "occupied_voxels": 90, "ms_per_frame": {"total": 1.0}, **extra}


def test_report_md_without_a_segmenter_says_what_the_scores_measure_instead_of_a_nan_column():
    md = render_report_md(_scored_report(semantics=GROUND_TRUTH_LABELS))
    assert "(None)" not in md and "nan" not in md
    assert f"No segmenter ran (semantics: {GROUND_TRUTH_LABELS})" in md
    assert "| measure | 3D map vs ground-truth voxels |" in md
    assert "| class | IoU, 3D map vs ground-truth voxels |" in md
    assert "The network alone" not in md
    with_segmenter = render_report_md(_scored_report(semantics="segmenter oracle", oracle_miou_2d=0.6,
                                                     oracle_pixel_accuracy_2d=0.7, oracle_mpa_2d=0.65))
    assert "| mIoU | **0.900** |" in with_segmenter and "No segmenter ran" not in with_segmenter
    assert "## The network alone (oracle)" in with_segmenter and "| MIoU | 0.600 |" in with_segmenter


# ---------------------------------------------------------------------------------------------- the objects rule
def test_every_listed_object_meets_the_rule_the_report_states(box_run):
    out, _ = box_run
    o = json.loads((out / "report.json").read_text())["objects"]
    params = ObjectMapParams()
    rule = o["kept_if_at_least"]
    assert rule == {"frames_seen": params.min_sightings, "sightings": params.min_keyframes}
    assert o["objects"] > 0 and len(o["table"]) == o["objects"]
    for row in o["table"]:
        assert row["frames_seen"] >= rule["frames_seen"] and row["sightings"] >= rule["sightings"], row
    stated = (f"tracked in at least {params.min_sightings} frames and mapped from at least {params.min_keyframes} "
              f"keyframes")
    assert stated in _words((out / "report.md").read_text())
    for doc in ("README.md", "docs/FIRST_STEPS.md"):  # the docs state the same rule
        text = _words((ROOT / doc).read_text())
        assert re.search(rf"at least {params.min_sightings} frames and (it was )?mapped from at least "
                         rf"{params.min_keyframes} keyframes", text), doc


# ---------------------------------------------------------------------------------------------- localization
def _estimate(x: float, converged: bool, spread_m: float = 0.02) -> PoseEstimate:
    return PoseEstimate(make_pose(np.eye(3), [x, 0.5, 1.0]), np.eye(6) * 1e-4, spread_m, 1.0, 0.95 if converged
                        else 0.6, 0.9, converged, 100.0, False, 0, 1.0, 0.05, {"total": 1.0})


@pytest.fixture(scope="module")
def localization():
    """A prior of two classes out of six and a run that converged on the true pose but lapsed at its end."""
    rng = np.random.default_rng(0)
    keys = np.unique(rng.integers(0, 20, (300, 3)), axis=0)
    labels = np.full((len(keys), 1), 2, np.uint16)
    labels[: len(keys) // 4, 0] = 5  # class 2 is the most frequent, then class 5
    prior = build_prior((keys + 0.5) * 0.05, 0.05, labels=labels, probs=np.ones((len(keys), 1), np.float32),
                        label_set=LabelSet.generic(6), cutoff=0.3, clearance=0.0)
    result = LocalizationResult(FilterSettings(particles=50), InitMode.TRACKING, "gt-noisy")
    for i, converged in enumerate([False, True, True, False]):
        est = _estimate(0.1 * i + 0.01, converged, 0.02 if converged else 0.15)
        result.updates.append(UpdateRecord(i, i / 10, f"{i}", est, 100, 1.0, 0.0, pos_err_m=0.01, rot_err_deg=0.5))
        result.ground_truth[i] = make_pose(np.eye(3), [0.1 * i, 0.5, 1.0])
        result.snapshots[i] = np.column_stack([rng.uniform(0, 1, (20, 3)), np.zeros(20)]).astype(np.float32)
    return result, prior


def test_the_localize_report_defines_reported_convergence_and_the_true_pose(localization):
    result, prior = localization
    report = report_dict(result, prior)
    s = report["summary"]
    assert s["converged_at_end"] is False and s["converged_to_truth"] is True
    md = _words(render_localize_md(report))
    assert "converged at the end: False" not in md
    assert ("Converged after **2 updates** (0.1 s of the sequence) by the filter's own test, without ground truth: "
            "its strongest particle cluster holds at least 90 %") in md
    assert "At the last update it did not" in md
    assert "On the true pose (against ground truth" in md and "**yes**" in md


def test_particles_png_has_a_legend_of_the_map_classes_it_shows(localization):
    result, prior = localization
    fig = particles_figure(result, prior)
    legend = next(lg for lg in fig.legends if lg.get_title().get_text() == "map classes")
    assert [t.get_text() for t in legend.get_texts()] == ["class_2", "class_5"]  # present only, most first
    assert particles_png(result, prior).startswith(b"\x89PNG")


# ---------------------------------------------------------------------------------------------- previews
@pytest.fixture
def drawn_text(monkeypatch) -> list[str]:
    """Every string the preview and objects pictures draw (cv2.putText), in order."""
    texts: list[str] = []
    real = cv2.putText

    def spy(img, text, *args, **kwargs):
        texts.append(text)
        return real(img, text, *args, **kwargs)

    monkeypatch.setattr(preview.cv2, "putText", spy)
    return texts


def _cloud(labels: list[int]) -> MapCloud:
    n = len(labels)
    rng = np.random.default_rng(1)
    return MapCloud(rng.uniform(0, 2, (n, 3)), np.full((n, 3), 128, np.uint8), np.asarray(labels, np.uint16),
                    np.ones(n, np.float32), 0.05)


def test_the_preview_legend_names_the_classes_it_shows_and_no_others(drawn_text):
    names = ("unknown", "wall", "floor", "chair", "lamp")
    label_set = LabelSet(names, np.array([[0, 0, 0], [200, 0, 0], [0, 200, 0], [0, 0, 200], [9, 9, 9]]))
    poses = [make_pose(np.eye(3), [1.0, 1.0, 1.5])]
    plain = preview.render_preview(_cloud([1] * 30 + [2] * 50 + [3] * 5), label_set, poses, legend=False)
    drawn_text.clear()
    image = preview.render_preview(_cloud([1] * 30 + [2] * 50 + [3] * 5), label_set, poses)
    legend = [t for t in drawn_text if t in names]
    assert legend == ["floor", "wall", "chair"]  # by voxels; lamp and unknown are not shown
    assert image.shape[1] == plain.shape[1] and image.shape[0] > plain.shape[0]  # the legend sits below


def test_a_long_legend_names_the_most_frequent_classes_and_counts_the_rest(drawn_text):
    label_set = LabelSet.generic(40)
    labels = [c for c in range(1, 40) for _ in range(c)]  # class 39 most frequent
    preview.with_class_legend(np.zeros((50, 600, 3), np.uint8), np.asarray(labels), label_set)
    assert drawn_text[0] == "class_39" and drawn_text[-1] == f"+{39 - preview.LEGEND_MAX_CLASSES} more"
    assert len(drawn_text) == preview.LEGEND_MAX_CLASSES + 1


def test_object_labels_never_overprint_and_the_largest_objects_keep_theirs():
    # a shelf of 40 books side by side, and two chairs far apart
    anchors = [np.array([100 + 2 * i, 100]) for i in range(40)] + [np.array([400, 300]), np.array([50, 350])]
    labels = [f"{i + 1} book" for i in range(40)] + ["41 chair", "42 chair"]
    sizes = [50 + i for i in range(40)] + [500, 400]
    kept = viz_objects.readable_labels(labels, anchors, sizes, (480, 400))
    assert 39 in kept and 40 in kept and 41 in kept  # the largest book and both chairs
    assert len(kept) < 10  # not forty labels on top of each other
    boxes = []
    for i, (x, y) in kept.items():
        (w, h), base = cv2.getTextSize(labels[i], viz_objects.FONT, viz_objects.FONT_SCALE, 3)
        boxes.append((x, y - h, x + w, y + base))
    for a in range(len(boxes)):
        for b in range(a + 1, len(boxes)):
            p, q = boxes[a], boxes[b]
            assert not (p[0] < q[2] and q[0] < p[2] and p[1] < q[3] and q[1] < p[3]), (p, q)


def test_the_trajectory_plot_uses_the_previews_axes_and_names_them(monkeypatch, tmp_path):
    figures = []
    monkeypatch.setattr(report_plots, "_save", lambda fig, path: figures.append(fig) or path)
    positions = np.array([[0.0, 0.0, 1.0], [1.0, 0.2, 1.0], [2.0, 1.0, 1.0]])
    camera = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # looking along y, image "up" is world +z
    used = Trajectory(np.arange(3.0), np.stack([make_pose(camera, p) for p in positions]), ("a", "b", "c"))
    report_plots.plot_trajectory(tmp_path / "t.png", used, None)
    ax = figures[0].axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (m)", "y (m)")
    e1, e2 = preview._horizontal_axes(np.array([0.0, 0.0, 1.0]))  # preview.png's top-down axes
    path = next(line for line in ax.lines if line.get_label().startswith("poses used"))
    assert np.allclose(path.get_xdata(), positions @ e1) and np.allclose(path.get_ydata(), positions @ e2)
    assert report_plots.axis_label(np.array([0.0, -1.0, 0.0])) == "−y (m)"


# ---------------------------------------------------------------------------------------------- precomputed names
@pytest.mark.slow
def test_precomputed_npy_predictions_take_the_datasets_class_names(boxes, tmp_path):
    preds = tmp_path / "preds"
    preds.mkdir()
    for frame in open_dataset(boxes, max_frames=4):
        onehot = np.zeros((*frame.labels.shape, len(INDOOR_LABELS)), np.float32)
        np.put_along_axis(onehot, frame.labels[..., None].astype(np.int64), 1.0, axis=-1)
        np.save(preds / f"{frame.name}.npy", onehot)
    out = tmp_path / "out"
    result = _cli("run", str(boxes), "--out", str(out), "--resolution", "0.1", "--max-frames", "4",
                  "--segmenter", "precomputed", "--weights", str(preds))
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    assert report["semantics"] == f"segmenter precomputed (predictions in {preds})"
    classes = set(report["voxels_per_class"])
    assert {"chair", "table"} <= classes and not any(name.startswith("class_") for name in classes)


# ---------------------------------------------------------------------------------------------- newcomer scripts
def _script(name: str):
    spec = importlib.util.spec_from_file_location(f"_first_contact_{name}", ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_make_test_bag_writes_a_bag_that_semmap_reads(boxes, tmp_path, kind):
    make_test_bag = _script("make_test_bag")
    out = tmp_path / ("tiny.bag" if kind == "ros1" else "tiny")
    assert make_test_bag.main([str(boxes), "--out", str(out), "--kind", kind, "--max-frames", "3"]) == 0
    frames = list(open_dataset(out))
    assert len(frames) == 3 and all(f.T_world_cam is not None for f in frames)
    assert make_test_bag.main([str(boxes), "--out", str(out)]) == 1  # never over an existing bag


def test_make_training_data_makes_a_small_set_on_request(tmp_path, monkeypatch):
    make_training_data = _script("make_training_data")
    rendered = []
    monkeypatch.setattr(make_training_data, "render", lambda out, plan, frames, size, realism="clean": rendered.append(
        (out.name, len(plan), frames, size)))
    make_training_data.main(["--out", str(tmp_path), "--scenes", "4", "--frames", "5"])
    assert rendered == [("train", 4, 5, (160, 120)), ("val", 2, 5, (160, 120))]  # 30 frames
    rendered.clear()
    make_training_data.main(["--out", str(tmp_path)])
    assert rendered == [("train", 120, 17, (160, 120)), ("val", 8, 10, (160, 120))]  # the shipped networks' set
    realisms = []
    monkeypatch.setattr(make_training_data, "render", lambda out, plan, frames, size, realism="clean": realisms.append(
        (out.name, realism)))
    make_training_data.main(["--out", str(tmp_path), "--scenes", "2", "--realism", "mixed"])
    assert realisms == [("train", "mixed"), ("val", "clean")]  # validation stays as the shipped nets were chosen
    with pytest.raises(SystemExit):
        make_training_data.main(["--out", str(tmp_path), "--frames", "0"])


def test_make_training_data_renders_extra_scenes_with_their_own_seeds(tmp_path, monkeypatch):
    """``--extra N``: N more training scenes into train-extra, seeds from 400 (disjoint from training 100-219,
    validation 300-307 and the test scenes 0-9), the same kind / size / path plan."""
    make_training_data = _script("make_training_data")
    rendered = []
    monkeypatch.setattr(make_training_data, "render", lambda out, plan, frames, size, realism="clean": rendered.append(
        (out.name, [p[0] for p in plan], frames)))
    make_training_data.main(["--out", str(tmp_path), "--extra", "5", "--image-size", "320x240"])
    names = [r[0] for r in rendered]
    assert names == ["train", "val", "train-extra"]
    extra = rendered[2][1]
    assert extra == [400, 401, 402, 403, 404] and rendered[2][2] == 17
    assert not set(extra) & (set(rendered[0][1]) | set(rendered[1][1]) | set(range(10)))
    kinds = [p[1:] for p in make_training_data.train_plan(make_training_data.EXTRA_SEEDS)[:4]]
    assert kinds == [p[1:] for p in make_training_data.train_plan()[:4]]  # the same plan
    with pytest.raises(SystemExit):
        make_training_data.main(["--out", str(tmp_path), "--extra", "-1"])
