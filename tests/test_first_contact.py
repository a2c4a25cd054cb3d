"""A first contact without surprises, the command line (issue 31, deliverable 7; Part 1 of the probe, frictions 5,
7, 9, 11): `track`, `localize`, `eval-seg` and `eval-traj` print a table like `run` and give the full JSON with
`--json` (or in their `--out` file); `eval-seg` takes K and the class names from the label set; no NumExpr line;
`info` and `view` read semmap's own objects.ply; Ctrl-C says one line; `simulate --image-size` only reduces;
`demo` and `localize` take `--trust-weights`; a bag without poses says how to get them, in one warning.

Every command runs in-process through `semmap.cli.main` (its one-line errors and exit codes) on tiny fixtures."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import make_room_frames, room_label_set, write_png
from semmap.io.trajectory import read_trajectory, write_trajectory


def cli(capsys, monkeypatch, *args: str) -> tuple[int, str, str]:
    """Run ``semmap ARGS`` in-process as the entry point does: (exit code, stdout, stderr)."""
    from semmap.cli import main

    monkeypatch.setenv("COLUMNS", "200")  # rich tables one row per line
    monkeypatch.setattr(sys, "argv", ["semmap", *map(str, args)])
    capsys.readouterr()
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    out = capsys.readouterr()
    return code, out.out, out.err


def table(text: str) -> dict[str, str]:
    """The rows ``key | value`` of a rich table printed to ``text``."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("│").split("│")]
        if len(cells) == 2 and cells[0]:
            rows[cells[0]] = cells[1]
    return rows


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    """A TUM sequence of 6 room frames with ground truth, labels and its labelset.json."""
    from semmap.io.tum_writer import write_tum_sequence

    root = tmp_path_factory.mktemp("first") / "room"
    write_tum_sequence(root, make_room_frames(6), label_set=room_label_set())
    return root


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """A simulated 3-frame sequence rendered at 160x120 (textured: odometry tracks it)."""
    from semmap.sim.export import simulate_sequence
    from semmap.types import CameraIntrinsics

    return simulate_sequence(tmp_path_factory.mktemp("first") / "sim", frames=3, size="small",
                             intrinsics=CameraIntrinsics(160, 120, 130.0, 130.0, 79.5, 59.5))


@pytest.fixture(scope="module")
def room_map(tmp_path_factory, room) -> Path:
    """map.semmap of the room (the prior `localize` takes)."""
    from semmap.geometry import backproject_world
    from semmap.io.native import save_map
    from semmap.maps.semantic_octomap import SemanticOctoMap
    from semmap.types import TopKProbs

    m = SemanticOctoMap(0.1, label_set=room_label_set())
    for f in make_room_frames(4):
        pts, pix = backproject_world(f.depth, f.intrinsics, f.T_world_cam)
        flat = TopKProbs.from_hard_labels(f.labels, 0.9, 7).reshape_flat()
        m.insert_points(pts, f.T_world_cam[:3, 3], semantics=TopKProbs(flat.labels[pix], flat.probs[pix]))
    path = tmp_path_factory.mktemp("prior") / "map.semmap"
    save_map(path, m)
    return path


# ------------------------------------------------------------------ tables, and the JSON with --json
def test_eval_traj_prints_a_table_and_the_full_json_with_json(room, tmp_path, capsys, monkeypatch) -> None:
    est = tmp_path / "est.txt"
    gt = read_trajectory(room / "groundtruth.txt")
    write_trajectory(est, gt)
    code, out, err = cli(capsys, monkeypatch, "eval-traj", room / "groundtruth.txt", est)
    assert code == 0 and out == ""  # the table goes beside the progress bars, not into a pipe
    rows = table(err)
    assert rows["ATE (SE(3) aligned)"] == "0.00 cm" and rows["poses matched"].startswith("6 ")
    assert {"RPE per frame", "Sim(3) scale", "ground-truth path"} <= set(rows)
    code, out, _ = cli(capsys, monkeypatch, "eval-traj", room / "groundtruth.txt", est, "--json")
    scores = json.loads(out)
    assert code == 0 and scores["matched"] == 6 and scores["ate_rmse_m"] < 1e-6 and "alignment" in scores


def test_eval_traj_compares_several_estimates_in_one_table(room, tmp_path, capsys, monkeypatch) -> None:
    gt = read_trajectory(room / "groundtruth.txt")
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    write_trajectory(a, gt)
    write_trajectory(b, gt)
    code, _, err = cli(capsys, monkeypatch, "eval-traj", room, a, b, "--pairwise")
    rows = table(err)
    assert code == 0 and rows["a"].startswith("ATE 0.00 cm") and rows["b"].startswith("ATE 0.00 cm")
    assert rows["a vs b"].startswith("0.00 cm apart")


@pytest.mark.slow
def test_track_prints_a_table_and_writes_its_trajectory(sim, tmp_path, capsys, monkeypatch) -> None:
    out = tmp_path / "traj.txt"
    code, stdout, err = cli(capsys, monkeypatch, "track", sim, "--out", out, "--method", "odometry")
    assert code == 0 and stdout == "", err
    rows = table(err)
    assert rows["method"] == "odometry" and rows["frames tracked"] == "3 of 3" and rows["trajectory"] == str(out)
    assert rows["ATE (SE(3) aligned)"].endswith(" cm") and rows["poses matched"] == "3"
    assert len(read_trajectory(out)) == 3
    code, stdout, _ = cli(capsys, monkeypatch, "track", sim, "--out", tmp_path / "t2.txt", "--method", "odometry",
                          "--json")
    summary = json.loads(stdout)
    assert code == 0 and summary["tracked"] == 3 and summary["matched"] == 3 and summary["method"] == "odometry"


def test_localize_prints_a_table_not_its_report(room, room_map, tmp_path, capsys, monkeypatch) -> None:
    import semmap.localization.sequence as sequence

    out, done = tmp_path / "loc", []
    real = sequence.localize_sequence
    monkeypatch.setattr(sequence, "localize_sequence", lambda *a, **k: done.append(real(*a, **k)) or done[-1])
    args = ("localize", room_map, room, "--max-frames", "3", "--particles", "200", "--init", "tracking",
            "--motion", "gt-noisy", "--out", out)
    code, stdout, err = cli(capsys, monkeypatch, *args)
    assert code == 0 and stdout == "", err
    rows = table(err)
    assert rows["filter"].startswith("200 particles, semantic model") and rows["updates"].startswith("3 ")
    assert rows["final error"].endswith("°") and rows["outputs"].startswith(f"{out}: ")
    assert "report.json" in rows["outputs"] and (out / "report.json").is_file()
    assert len(err.splitlines()) < 30  # was: 59 lines of report.json
    monkeypatch.setattr(sequence, "localize_sequence", lambda *a, **k: done[0])  # the same result, with --json
    code, stdout, _ = cli(capsys, monkeypatch, *args, "--json")
    summary = json.loads(stdout)
    assert code == 0 and summary["updates"] == 3 and "report.json" in summary["files"]
    assert summary["pos_err_m_final"] == json.loads((out / "report.json").read_text())["summary"]["pos_err_m_final"]


# ------------------------------------------------------------------ eval-seg and the label set
@pytest.fixture
def label_folders(tmp_path) -> tuple[Path, Path]:
    """A 30-class sequence's labels/ with its labelset.json beside (as `semmap simulate` writes them), and
    predictions: ids 1 (wall) and 29 right, id 2 (floor) half wrong."""
    from semmap.labels import INDOOR_LABELS

    assert len(INDOOR_LABELS) == 30
    gt = np.zeros((4, 8), np.uint8)
    gt[:, :2], gt[:, 2:6], gt[:, 6:] = 1, 2, 29
    pred = gt.copy()
    pred[:2, 2:6] = 1
    write_png(tmp_path / "seq" / "labels" / "0.png", gt)
    write_png(tmp_path / "pred" / "0.png", pred)
    INDOOR_LABELS.save(tmp_path / "seq" / "labelset.json")
    return tmp_path / "pred", tmp_path / "seq" / "labels"


def test_eval_seg_takes_k_and_class_names_from_the_label_set(label_folders, tmp_path, capsys, monkeypatch) -> None:
    from semmap.labels import INDOOR_LABELS

    pred, gt = label_folders
    code, stdout, err = cli(capsys, monkeypatch, "eval-seg", pred, gt, "--out", tmp_path / "scores.json")
    assert code == 0 and stdout == "", err  # the default no longer fails on semmap's own 30 classes
    rows = table(err)
    assert rows["classes"] == f"30 from {gt.parent / 'labelset.json'}"
    wall, floor, last = (f"IoU {INDOOR_LABELS.names[i]}" for i in (1, 2, 29))
    assert rows[floor].startswith("0.5000") and rows[last].startswith("1.0000") and wall in rows
    assert rows["images"] == "1 scored, 0 without a prediction" and rows["scores written to"] == str(
        tmp_path / "scores.json")
    saved = json.loads((tmp_path / "scores.json").read_text())
    assert saved["num_classes"] == 30 and set(saved["per_class"]) == {INDOOR_LABELS.names[i] for i in (1, 2, 29)}
    assert len(saved["confusion"]) == 30
    code, stdout, _ = cli(capsys, monkeypatch, "eval-seg", pred, gt, "--json")
    assert code == 0 and json.loads(stdout)["per_class"][INDOOR_LABELS.names[2]]["iou"] == 0.5


def test_eval_seg_without_a_label_set_infers_k_and_a_disagreeing_k_is_one_line(label_folders, capsys,
                                                                                 monkeypatch) -> None:
    pred, gt = label_folders
    code, _, err = cli(capsys, monkeypatch, "eval-seg", pred, gt, "--num-classes", "21")
    assert code == 1 and err.strip().count("\n") == 0
    assert "--num-classes 21 disagrees with the 30 classes of" in err and "labelset.json" in err
    (gt.parent / "labelset.json").unlink()
    code, _, err = cli(capsys, monkeypatch, "eval-seg", pred, gt)
    rows = table(err)
    assert code == 0 and rows["classes"] == "30 (ids 0..29, no labelset.json)" and "IoU 29" in rows
    code, _, err = cli(capsys, monkeypatch, "eval-seg", pred, gt, "--num-classes", "21")
    assert code == 1 and "class id 29 is not below --num-classes 21" in err and err.strip().count("\n") == 0


def test_the_readme_eval_seg_example_names_no_fixed_class_count() -> None:
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    line = next(x for x in readme.splitlines() if "semmap eval-seg" in x)
    assert "--num-classes 21" not in line


# ------------------------------------------------------------------ no NumExpr line
def test_no_numexpr_line_once_logging_is_set_up(capsys) -> None:
    import logging

    from semmap.cli import _setup_logging

    _setup_logging(False)
    logging.getLogger("numexpr.utils").info("NumExpr defaulting to 2 threads.")  # numexpr's own logger and words
    logging.getLogger("semmap").warning("still heard")
    err = capsys.readouterr().err
    assert "NumExpr" not in err and "still heard" in err


# ------------------------------------------------------------------ info and view read objects.ply
@pytest.fixture
def objects_ply(tmp_path) -> Path:
    """objects.json and objects.ply of three objects: two chairs and a table."""
    from semmap.io.objects import write_objects_json, write_objects_ply
    from semmap.labels import INDOOR_LABELS
    from semmap.maps.objects import MapObject

    chair, table_id = INDOOR_LABELS.names.index("chair"), INDOOR_LABELS.names.index("table")
    objects = []
    for oid, cls, n in ((1, chair, 5), (2, chair, 4), (3, table_id, 6)):
        votes = np.zeros(len(INDOOR_LABELS), np.float32)
        votes[cls] = 1.0
        pts = np.random.default_rng(oid).uniform(0, 1, (n, 3)).astype(np.float32) + oid
        empty = np.zeros(0, np.int64)
        objects.append(MapObject(oid, votes, np.arange(n, dtype=np.int64), pts, np.zeros((n, 3), np.uint8),
                                 empty, empty, empty, sightings=3, class_id=cls))
    write_objects_json(tmp_path / "objects.json", objects, INDOOR_LABELS, np.array([0.0, 0.0, 1.0]))
    write_objects_ply(tmp_path / "objects.ply", objects)
    return tmp_path / "objects.ply"


def test_info_describes_semmaps_own_objects_ply(objects_ply, capsys, monkeypatch) -> None:
    code, stdout, err = cli(capsys, monkeypatch, "info", objects_ply)
    assert code == 0, err
    d = json.loads(stdout)
    assert d["kind"] == "objects" and d["points"] == 15 and d["objects"] == 3
    assert d["objects_per_class"] == {"chair": 2, "table": 1} and d["classes_present"] == 2
    (objects_ply.parent / "objects.json").unlink()  # without it, classes by id
    assert len(json.loads(cli(capsys, monkeypatch, "info", objects_ply)[1])["objects_per_class"]) == 2


def test_view_saves_semmaps_own_objects_ply(objects_ply, tmp_path, capsys, monkeypatch) -> None:
    code, _, err = cli(capsys, monkeypatch, "view", objects_ply, "--save", tmp_path / "objects.rrd")
    assert code == 0, err
    assert "15" in err and (tmp_path / "objects.rrd").stat().st_size > 0


# ------------------------------------------------------------------ Ctrl-C: one line
@pytest.mark.parametrize("command", ["track", "localize", "simulate"])
def test_ctrl_c_in_track_localize_and_simulate_is_one_line_and_130(command, room, room_map, tmp_path, capsys,
                                                                   monkeypatch) -> None:
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("semmap.runner.track_to_file", interrupted)
    monkeypatch.setattr("semmap.localization.sequence.localize_sequence", interrupted)
    monkeypatch.setattr("semmap.sim.export._write_sequence", interrupted)  # simulate stages, then says so
    args = {"track": ["track", room, "--out", tmp_path / "t.txt"],
            "localize": ["localize", room_map, room, "--out", tmp_path / "loc"],
            "simulate": ["simulate", "--out", tmp_path / "sim", "--frames", "2"]}[command]
    code, _, err = cli(capsys, monkeypatch, *args)
    expected = (f"semmap: interrupted while rendering; nothing written to {tmp_path / 'sim'}"
                if command == "simulate" else "semmap: interrupted")
    assert code == 130 and err.strip() == expected


@pytest.mark.slow
def test_ctrl_c_after_the_last_frame_keeps_the_complete_outputs_and_exits_0(room, tmp_path, capsys,
                                                                           monkeypatch) -> None:
    from semmap.pipeline import Pipeline

    write = Pipeline._write

    def late_ctrl_c(self, outcome):
        report = write(self, outcome)
        os.kill(os.getpid(), signal.SIGINT)  # lands while the run finishes (the handler only sets the flag)
        return report

    monkeypatch.setattr(Pipeline, "_write", late_ctrl_c)
    out = tmp_path / "run"
    code, _, err = cli(capsys, monkeypatch, "run", room, "--out", out, "--resolution", "0.2")
    assert code == 0, err
    assert f"Ctrl-C after the last frame: the run finished writing; its outputs in {out} are complete" in err
    assert json.loads((out / "report.json").read_text())["frames_used"] == 6 and (out / "map.ot").is_file()


# ------------------------------------------------------------------ simulate --image-size only reduces
def test_simulate_image_size_only_reduces(tmp_path, capsys, monkeypatch) -> None:
    code, _, err = cli(capsys, monkeypatch, "simulate", "--out", tmp_path / "sim", "--frames", "1",
                       "--image-size", "1280x960")
    assert code == 1 and err.strip().count("\n") == 0
    assert "--image-size 1280x960 is larger than the native 640x480" in err
    assert not (tmp_path / "sim").exists()


# ------------------------------------------------------------------ --trust-weights on demo and localize
@pytest.mark.parametrize("command", ["demo", "localize"])
def test_demo_and_localize_offer_trust_weights(command, capsys, monkeypatch) -> None:
    code, stdout, _ = cli(capsys, monkeypatch, command, "--help")
    assert code == 0 and "--trust-weights" in stdout


@pytest.fixture
def changed_shipped_fcn(tmp_path, monkeypatch) -> Path:
    """Shipped weights ($SEMMAP_WEIGHTS) whose fcn.pt (the room's 7 classes) differs from the manifest's sha256;
    the manifest names fcn the demo's network."""
    import torch

    from semmap.perception.networks.registry import NetworkSpec, build_network, save_weights

    folder = tmp_path / "weights"
    folder.mkdir()
    torch.manual_seed(0)
    spec = NetworkSpec("fcn", num_classes=7, width=0.25, depth=18)
    save_weights(folder / "fcn.pt", build_network(spec), spec, room_label_set(), (80, 60))
    assert hashlib.sha256((folder / "fcn.pt").read_bytes()).hexdigest() != "0" * 64
    (folder / "manifest.json").write_text(json.dumps({"networks": {"fcn": {"file": "fcn.pt", "sha256": "0" * 64}},
                                                      "demo": {"network": "fcn"}}))
    monkeypatch.setenv("SEMMAP_WEIGHTS", str(folder))
    return folder


def test_localize_trust_weights_reaches_the_segmenter(changed_shipped_fcn, room, room_map, tmp_path, capsys,
                                                      monkeypatch) -> None:
    import semmap.localization.sequence as sequence
    from semmap.datasets import open_dataset
    from semmap.errors import ConfigError
    from semmap.localization.prior import load_prior

    args = ("localize", room_map, room, "--max-frames", "2", "--segmenter", "fcn", "--out", tmp_path / "loc")
    code, _, err = cli(capsys, monkeypatch, *args)
    assert code == 1 and "differs from" in err and "--trust-weights" in err and err.strip().count("\n") == 0
    prior, dataset = load_prior(room_map), open_dataset(room, max_frames=2)
    with pytest.raises(ConfigError, match="--trust-weights"):
        sequence._segment_fn(sequence.LocalizeOptions(segmenter="fcn"), dataset, prior)
    assert sequence._segment_fn(sequence.LocalizeOptions(segmenter="fcn", trust_weights=True), dataset, prior)
    assert "used anyway (--trust-weights)" in capsys.readouterr().err  # (semmap's log handler, set up by cli)
    asked = []

    def stop_here(map_path, seq, out, options, **kwargs):
        asked.append(options)
        raise ConfigError("stopped before localizing")

    monkeypatch.setattr(sequence, "localize_sequence", stop_here)
    assert cli(capsys, monkeypatch, *args, "--trust-weights")[0] == 1
    assert asked[0].trust_weights is True and asked[0].segmenter == "fcn"


def test_demo_trust_weights_reaches_the_segmenter(changed_shipped_fcn, tmp_path) -> None:
    from semmap.errors import ConfigError
    from semmap.factories import segmenter_for
    from semmap.runner import demo_config

    config, _ = demo_config(out=tmp_path / "demo", frames=1)
    assert config.semantics.segmenter == "fcn" and not config.semantics.trust_weights
    with pytest.raises(ConfigError, match="--trust-weights"):
        segmenter_for(config)
    trusting, _ = demo_config(out=tmp_path / "demo", frames=1, trust_weights=True)
    assert segmenter_for(trusting) is not None


# ------------------------------------------------------------------ a bag without poses
def test_a_bag_without_poses_warns_once_and_points_to_a_tracker(tmp_path, capsys, monkeypatch) -> None:
    from ros_helpers import write_bag

    bag = write_bag(tmp_path / "bare.bag", make_room_frames(4), poses="none")
    code, _, err = cli(capsys, monkeypatch, "run", bag, "--out", tmp_path / "o")
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 1 and not (tmp_path / "o").exists()
    assert sum("has no pose" in line for line in lines) == 1, err
    assert "without pose" in lines[-1] and "--poses slam or --poses odometry" in lines[-1]
    assert "groundtruth.txt" not in lines[-1]
