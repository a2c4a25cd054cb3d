"""Issue 31, the input-side cases of the 2026-11-25 probe (S2-S6, S14-S16, U1-U24, M5, M10, H1/M3/U21): every
damaged or odd input is refused in one line naming the file, frame or option (or skipped with a warning naming it),
with exit code 1 and no traceback, before the work it would spoil. Each fixture is rebuilt here in a few lines."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import ROOM_CAMERA, make_room_frames, room_label_set
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.types import Observation, TopKProbs


def cli(capsys, monkeypatch, *args: object) -> tuple[int, str, str]:
    """Run ``semmap ARGS`` in this process as the console script does: (exit code, stdout, stderr)."""
    from semmap.cli import main

    monkeypatch.setattr(sys, "argv", ["semmap", *map(str, args)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    out, err = capsys.readouterr()
    code = exit_info.value.code
    return (code if isinstance(code, int) else 0 if code is None else 1), out, err


def refused(capsys, monkeypatch, *args: object) -> str:
    """The one-line error of a command that must fail (exit 1, no traceback)."""
    code, out, err = cli(capsys, monkeypatch, *args)
    assert code == 1, (out, err)
    assert "Traceback" not in err + out
    lines = [line for line in err.splitlines() if line.startswith("semmap: error: ")]
    assert len(lines) == 1, err
    return lines[0]


# ---------------------------------------------------------------------------------------------- map files
def _observation() -> Observation:
    rng = np.random.default_rng(0)
    points = rng.uniform([-1, -1, 1], [1, 1, 2], (300, 3)).astype(np.float32)
    sem = TopKProbs.from_hard_labels(rng.integers(0, 7, 300).astype(np.uint16), 0.9, 7)
    return Observation(points, np.zeros(3), np.full((300, 3), 200, np.uint8), sem)


@pytest.fixture(scope="module")
def maps(tmp_path_factory) -> Path:
    """``map.ot``, ``map.bt``, ``map.semmap`` of a tiny OctoMap and ``voxelgrid.semmap``, ``voxelgrid.ply`` of a tiny
    voxel grid."""
    from semmap.io.map_files import save_map_files
    from semmap.maps.voxel_grid import SemanticVoxelGrid

    root = tmp_path_factory.mktemp("maps")
    for m in (SemanticOctoMap(0.1, label_set=room_label_set()),
              SemanticVoxelGrid(0.1, label_set=room_label_set(), free_space=True)):
        m.integrate(_observation())
        save_map_files(m, root)
    return root


def _rewrite_npz(src: Path, dst: Path, **changes) -> Path:
    """A copy of the zip of arrays ``src`` with some arrays (by name) replaced by the functions of their old value."""
    with np.load(src) as z:
        arrays = {name: z[name] for name in z.files}
    for name, change in changes.items():
        arrays[name] = change(arrays[name])
    with open(dst, "wb") as f:
        np.savez_compressed(f, **arrays)
    return dst


def _with_header(src: Path, dst: Path, **fields) -> Path:
    """A copy of a ``.semmap`` with some header fields changed."""
    def change(raw: np.ndarray) -> np.ndarray:
        header = {**json.loads(raw.tobytes()), **fields}
        return np.frombuffer(json.dumps(header).encode(), np.uint8)
    return _rewrite_npz(src, dst, header=change)


def _nan(a: np.ndarray) -> np.ndarray:
    return np.full_like(a, np.nan)


@pytest.mark.slow
def test_s3_a_voxel_grid_with_nan_log_odds_is_refused_by_info_and_view(maps, tmp_path, capsys, monkeypatch):
    bad = _rewrite_npz(maps / "voxelgrid.semmap", tmp_path / "all_nan_vg.semmap", logodds=_nan)
    for args in (["info", bad], ["view", bad, "--save", tmp_path / "v.rrd"]):
        line = refused(capsys, monkeypatch, *args)
        assert str(bad) in line and "non-finite" in line and "log-odds" in line
    assert not (tmp_path / "v.rrd").exists()


@pytest.mark.parametrize("member", ["dense", "geo_logodds"])
def test_s3_every_float_array_of_a_grid_file_is_checked(maps, tmp_path, capsys, monkeypatch, member):
    from semmap.io.map_files import load_map

    src = maps / "voxelgrid.semmap"
    with np.load(src) as z:
        if member not in z.files or z[member].size == 0:
            pytest.skip(f"this grid has no {member}")
    bad = _rewrite_npz(src, tmp_path / "bad.semmap", **{member: _nan})
    with pytest.raises(Exception, match=r"bad\.semmap: .*non-finite"):
        load_map(bad)


def test_s4_a_ply_with_nan_coordinates_is_refused(maps, tmp_path, capsys, monkeypatch):
    data = bytearray((maps / "voxelgrid.ply").read_bytes())
    start = data.index(b"end_header\n") + len(b"end_header\n")
    data[start:start + 4] = np.float32(np.nan).tobytes()  # the first vertex's x
    bad = tmp_path / "ply_nan.ply"
    bad.write_bytes(bytes(data))
    for args in (["info", bad], ["view", bad, "--save", tmp_path / "v.rrd"]):
        line = refused(capsys, monkeypatch, *args)
        assert str(bad) in line and "non-finite" in line


@pytest.mark.parametrize("res", ["1e+300", "1e-300", "11.0"])
@pytest.mark.parametrize("name", ["map.ot", "map.bt"])
def test_s5_an_octomap_file_resolution_outside_the_limits_is_refused(maps, tmp_path, capsys, monkeypatch, res,
                                                                   name):
    bad = tmp_path / f"res{res}{Path(name).suffix}"
    bad.write_bytes((maps / name).read_bytes().replace(b"res 0.1\n", f"res {res}\n".encode(), 1))
    for args in (["info", bad], ["view", bad, "--save", tmp_path / "v.rrd"]):
        line = refused(capsys, monkeypatch, *args)
        assert str(bad) in line and "resolution must be from 0.001 to 10" in line


@pytest.mark.parametrize("name", ["map.semmap", "voxelgrid.semmap"])
def test_u22_a_semmap_resolution_outside_the_limits_names_the_file(maps, tmp_path, capsys, monkeypatch, name):
    bad = _with_header(maps / name, tmp_path / "res_huge.semmap", resolution=1e308)
    line = refused(capsys, monkeypatch, "info", bad)
    assert str(bad) in line and "resolution must be from 0.001 to 10" in line


@pytest.mark.slow
def test_the_good_map_files_still_read(maps, capsys, monkeypatch):
    for name in ("map.ot", "map.bt", "map.semmap", "voxelgrid.semmap", "voxelgrid.ply"):
        code, _out, err = cli(capsys, monkeypatch, "info", maps / name)
        assert code == 0, err


# ---------------------------------------------------------------------------------------------- sequences
def _tum(root: Path, frames=None) -> Path:
    """A TUM sequence of ``frames`` (default: three frames of the analytic room, with labels and a label set)."""
    from semmap.io.tum_writer import write_tum_sequence

    write_tum_sequence(root, frames if frames is not None else make_room_frames(3), label_set=room_label_set())
    return root


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    """The three-frame sequence the cases below copy and break (never changed itself)."""
    return _tum(tmp_path_factory.mktemp("seq") / "seq")


def _copy(seq: Path, dst: Path) -> Path:
    import shutil

    return Path(shutil.copytree(seq, dst))


def _static(root: Path, n: int = 4) -> Path:
    """A sequence whose camera never moves: one frame ``n`` times with its ground truth."""
    frame = make_room_frames(1)[0]
    return _tum(root, [frame.with_(index=i, timestamp=i / 30, name=f"{i / 30:.6f}") for i in range(n)])


def _append_row(path: Path, row: str) -> None:
    path.write_text(path.read_text() + row + "\n")


def _run_args(seq: Path, out: Path, *more: object) -> list[object]:
    return ["run", seq, "--out", out, "--resolution", "0.2", *more]


def test_m10_a_huge_rgb_list_is_read_only_as_far_as_max_frames_needs(seq, tmp_path, monkeypatch):
    from semmap.datasets import tum

    big = _copy(seq, tmp_path / "tum_huge_rgbtxt")
    rows = "".join(f"{1000 + i / 30:.6f} rgb/missing.png\n" for i in range(50_000))
    (big / "rgb.txt").write_text((big / "rgb.txt").read_text() + rows)
    parsed = []
    real_stamp = tum._stamp
    monkeypatch.setattr(tum, "_stamp", lambda path, number, field: parsed.append(path.name) or
                        real_stamp(path, number, field))
    dataset = tum.TumDataset(big, max_frames=2)
    assert len(dataset) == 2 and [f.name for f in dataset] == ["0.000000", "0.033333"]
    assert parsed.count("rgb.txt") <= 2 + tum.READ_MARGIN
    assert len(tum.TumDataset(big)) == 3  # (without --max-frames the whole list is read)


@pytest.mark.parametrize("where", ["est", "gt"])
def test_s6_eval_traj_refuses_absurd_positions_naming_the_file(seq, tmp_path, capsys, monkeypatch, where):
    gt = seq / "groundtruth.txt"
    big = tmp_path / "big.txt"
    big.write_text("\n".join(f"{i / 30:.6f} 1e300 -1e300 1e300 0 0 0 1" for i in range(3)) + "\n")
    args = ["eval-traj", gt, big] if where == "est" else ["eval-traj", big, gt]
    line = refused(capsys, monkeypatch, *args)
    assert f"{big}:1: " in line and "beyond" in line


def test_u24_eval_traj_on_a_folder_without_poses_names_the_folder(seq, tmp_path, capsys, monkeypatch):
    bare = _copy(seq, tmp_path / "tum_gt_missing")
    (bare / "groundtruth.txt").unlink()
    line = refused(capsys, monkeypatch, "eval-traj", bare, seq / "groundtruth.txt")
    assert str(bare) in line and "no ground-truth poses" in line


@pytest.mark.slow
def test_u2_u4_a_static_camera_is_scored_with_a_warning_not_refused(tmp_path, capsys, monkeypatch):
    static = _static(tmp_path / "tum_static")
    gt = static / "groundtruth.txt"
    code, out, err = cli(capsys, monkeypatch, "eval-traj", gt, gt, "--json")
    assert code == 0, err
    scores = json.loads(out)
    assert scores["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9) and scores["sim3_scale"] is None
    assert "Umeyama alignment is not possible" in scores["alignment_not_possible"]
    assert "NaN" not in out and "Infinity" not in out
    code, out, err = cli(capsys, monkeypatch, "track", static, "--out", tmp_path / "t.txt", "--method", "odometry")
    assert code == 0, err
    assert (tmp_path / "t.txt").is_file() and "no Sim(3) scale" in err
    code, out, err = cli(capsys, monkeypatch, *_run_args(static, tmp_path / "o", "--poses", gt))
    assert code == 0, err
    assert (tmp_path / "o" / "map.ot").is_file() and (tmp_path / "o" / "report.json").is_file()


def _move_gt_row(bad: Path, row: int, position: str) -> None:
    """Ground-truth row ``row`` of the sequence ``bad`` puts the camera at ``position`` (three numbers)."""
    lines = (bad / "groundtruth.txt").read_text().splitlines()
    data = [i for i, line in enumerate(lines) if not line.startswith("#")]
    fields = lines[data[row]].split()
    lines[data[row]] = " ".join([fields[0], *position.split(), *fields[4:]])
    (bad / "groundtruth.txt").write_text("\n".join(lines) + "\n")


@pytest.mark.slow
def test_s2_u1_u8_bad_frames_are_skipped_or_named_and_the_others_mapped(tmp_path, capsys, monkeypatch):
    """One sequence with one of each: frame 0's time repeated in rgb.txt and depth.txt (U1), frame 1 posed 10^6 m
    away (S2), frame 2 posed at 1e300 (U8), frame 3 without depth in range (S2); frame 4 is good."""
    from helpers import write_png

    bad = _tum(tmp_path / "bad", make_room_frames(5))
    for name, folder in (("rgb.txt", "rgb"), ("depth.txt", "depth")):
        _append_row(bad / name, f"0.000000 {folder}/0.033333.png")  # a second row at the first frame's time
    _move_gt_row(bad, 1, "1e6 0 0")
    _move_gt_row(bad, 2, "1e300 -1e300 1e300")
    write_png(bad / "depth" / "0.100000.png", np.zeros((ROOM_CAMERA.height, ROOM_CAMERA.width), np.uint16))
    code, _out, err = cli(capsys, monkeypatch, *_run_args(bad, tmp_path / "o"))
    assert code == 0, err
    said = " ".join(err.split())
    assert "rgb.txt: 1 rows repeat an earlier timestamp; at most one row per timestamp is used" in said
    assert "frame 0.033333 has no pose (its camera lies 1,000,000 m from the origin, beyond the ±6,554 m" in said
    assert "groundtruth.txt: 1 poses have non-finite entries or positions beyond ±1e+08 m (lines 5)" in said
    assert "2 frames had no pose and were skipped (0.033333 ... 0.066667)" in said  # one warning, then the count
    assert "frame 0.100000 adds nothing to the map: no depth pixel lies between --min-depth" in said
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["frames_used"] == 3 and report["frames_skipped"] == 2


@pytest.mark.parametrize("case", ["tum_label_oob", "tum_ls_few"])
def test_u5_u7_a_label_id_outside_the_label_set_names_the_file_and_frame(seq, tmp_path, capsys, monkeypatch, case):
    from helpers import write_png
    from semmap.types import LabelSet

    bad = _copy(seq, tmp_path / case)
    if case == "tum_label_oob":
        write_png(bad / "labels" / "0.000000.png", np.full((ROOM_CAMERA.height, ROOM_CAMERA.width), 200, np.uint8))
    else:
        LabelSet(("unknown", "thing"), np.zeros((2, 3), np.uint8)).save(bad / "labelset.json")
    line = refused(capsys, monkeypatch, *_run_args(bad, tmp_path / "o"))
    assert f"{bad / 'labels' / '0.000000.png'}: label id" in line and "of frame 0.000000" in line
    assert not (tmp_path / "o").exists()


def test_u10_a_bag_whose_colour_topic_is_the_depth_topic_says_which_topic_holds_what(tmp_path):
    from ros_helpers import DEPTH, RGB, write_bag
    from semmap.datasets import open_dataset
    from semmap.errors import DatasetError

    path = write_bag(tmp_path / "rec.bag", make_room_frames(2))
    with pytest.raises(DatasetError) as info:
        open_dataset(path, ros={"rgb_topic": DEPTH})
    message = str(info.value)
    assert f"{DEPTH} is both the colour and the depth topic" in message
    assert f"{DEPTH} (16UC1)" in message and f"{RGB} (rgb8)" in message


# ---------------------------------------------------------------------------------------------- named paths
def _special(tmp_path: Path, kind: str) -> Path:
    import os

    if kind == "folder":
        (tmp_path / "w").mkdir()
        return tmp_path / "w"
    if kind == "fifo":
        os.mkfifo(tmp_path / "fifo.pt")
        return tmp_path / "fifo.pt"
    return Path("/dev/zero")


@pytest.mark.parametrize("kind, says", [("folder", "is a folder"), ("device", "is a device"), ("fifo", "is a FIFO")])
def test_u16_u18_weights_that_are_not_a_file_say_what_they_are(tmp_path, kind, says):
    from semmap.errors import FormatError
    from semmap.perception.espnetv2 import load_espnetv2
    from semmap.perception.networks.registry import load_weights

    path = _special(tmp_path, kind)
    for load in (load_weights, load_espnetv2):
        with pytest.raises(FormatError, match=rf"^{path}: {says}, expected"):
            load(path)


def test_u19_poses_that_name_a_folder_say_it_is_a_folder(seq, tmp_path, capsys, monkeypatch):
    (tmp_path / "traj").mkdir()
    line = refused(capsys, monkeypatch, *_run_args(seq, tmp_path / "o", "--poses", tmp_path / "traj"))
    assert f"{tmp_path / 'traj'} is a folder" in line and "--poses" in line


def test_u20_localize_on_an_octomap_file_says_it_needs_a_semmap_map(maps, tmp_path, seq, capsys, monkeypatch):
    line = refused(capsys, monkeypatch, "localize", maps / "map.ot", seq, "--out", tmp_path / "l")
    assert str(maps / "map.ot") in line and "localize needs a semmap map" in line and "map.semmap" in line


def test_u23_a_batch_config_that_is_not_an_object_names_the_file(seq, tmp_path, capsys, monkeypatch):
    config = tmp_path / "list.json"
    config.write_text("[1, 2]")
    line = refused(capsys, monkeypatch, "batch", seq, "--out", tmp_path / "b", "--config", config)
    assert f"{config}: " in line and "object" in line


# ---------------------------------------------------------------------------------------------- semantics, training
def test_s14_semantics_labels_without_labels_is_refused_before_mapping(seq, tmp_path, capsys, monkeypatch):
    import shutil

    bare = _copy(seq, tmp_path / "nolabels")
    shutil.rmtree(bare / "labels")
    (bare / "labelset.json").unlink()
    line = refused(capsys, monkeypatch, *_run_args(bare, tmp_path / "o", "--semantics", "labels"))
    assert str(bare) in line and "--semantics labels" in line and "--labels" in line
    assert not (tmp_path / "o").exists()


def _plain_training_folder(root: Path, label: int) -> Path:
    """A plain training folder of two 32x24 images whose labels are all ``label``."""
    from helpers import write_png

    for i in range(2):
        write_png(root / "images" / f"f{i}.png", np.full((24, 32, 3), 60 * i, np.uint8))
        write_png(root / "labels" / f"f{i}.png", np.full((24, 32), label, np.uint8))
    room_label_set().save(root / "labelset.json")
    return root


def test_s15_training_on_void_labels_only_is_refused_naming_the_folder(tmp_path, capsys, monkeypatch):
    data = _plain_training_folder(tmp_path / "plain_alllabel0", 0)
    line = refused(capsys, monkeypatch, "train", "--model", "fcn", "--data", data, "--out", tmp_path / "t",
                   "--iterations", "2", "--batch", "2", "--input-size", "32x24", "--threads", "1")
    assert str(data) in line and "every label pixel is 0" in line
    assert not (tmp_path / "t").exists()


def test_s16_training_with_a_zero_depth_scale_is_refused(tmp_path, capsys, monkeypatch):
    data = _plain_training_folder(tmp_path / "plain", 1)
    line = refused(capsys, monkeypatch, "train", "--model", "rgbd-net", "--data", data, "--out", tmp_path / "t",
                   "--depth-scale", "0")
    assert "--depth-scale must be a number from" in line


# ---------------------------------------------------------------------------------------------- memory of a run
@pytest.fixture
def budget_2m():
    from semmap import limits

    limits.set_memory_budget("2M")
    yield
    limits.set_memory_budget(None)


@pytest.mark.slow
def test_h1_m3_the_maps_are_checked_against_the_budget_after_every_frame(budget_2m):
    from semmap.limits import MemoryBudgetError
    from semmap.maps.voxel_grid import SemanticVoxelGrid
    from semmap.pipeline import Mapper
    from semmap.types import CameraIntrinsics

    rng = np.random.default_rng(1)
    camera = CameraIntrinsics(320, 240, 200.0, 200.0, 159.5, 119.5)
    depth = rng.uniform(1.0, 3.0, (240, 320)).astype(np.float32)
    rgb = np.zeros((240, 320, 3), np.uint8)
    mapper = Mapper([SemanticVoxelGrid(0.01)], min_depth=0.1, max_depth=8.0)
    with pytest.raises(MemoryBudgetError, match=r"--resolution 0\.01: the maps hold .* after frame 7 and grew .*"
                                                r"past the budget of 2\.1 MB \(--memory-budget\); choose a coarser"):
        mapper.integrate_arrays(rgb, depth, camera, np.eye(4), index=7)


def test_u21_a_range_cut_by_a_too_fine_resolution_says_so(caplog):
    from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
    from semmap.run.outputs import warn_if_empty

    m = SemanticOctoMap(0.01, grid_cell_limit=4096)
    obs = _observation()
    m.integrate(Observation(obs.points_world * 3, obs.origin, obs.colors))
    cut = m.range_cut_m
    assert cut is not None and 0 < cut < 0.1
    config = RunConfig(input=InputConfig(dataset=Path("x")), mapping=MappingConfig(resolution=0.01),
                       output=OutputConfig(out=Path("o")))
    warn_if_empty(m, config, 300, [np.eye(4)])
    text = " ".join(caplog.text.split())
    assert "--resolution 0.01 m is too fine for the range of the scans" in text
    assert f"readings beyond {cut:.2f} m were cut off; choose a coarser --resolution" in text
    assert "check the poses and depth units" not in text


def test_h1_ground_truth_voxels_beyond_the_budget_leave_the_3d_score_out_with_a_warning(budget_2m, caplog):
    from types import SimpleNamespace

    from semmap.eval.run_report import RunScorer
    from semmap.limits import MemoryBudgetError
    from semmap.sim.ground_truth import gt_voxels

    scene = SimpleNamespace(vertices=np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], np.float32),
                            triangles=np.array([[0, 1, 2]]), tri_class=np.array([1]), tri_instance=np.array([1]))
    with pytest.raises(MemoryBudgetError, match=r"--resolution 0\.002 over the simulated scene's 50 m² of surface"):
        gt_voxels(scene, 0.002)
    m = SemanticOctoMap(0.002, label_set=room_label_set())
    assert RunScorer(lambda res: gt_voxels(scene, res), 0.002).map_3d(m) == {}
    assert "the map is not scored in 3D: --resolution 0.002" in caplog.text


def test_m5_a_crf_beyond_the_budget_is_refused_before_its_lattices_and_the_run_keeps_the_map(budget_2m, caplog):
    from semmap.eval.run_report import RunScorer
    from semmap.fusion.crf import CrfParams, refine_map
    from semmap.limits import MemoryBudgetError
    from semmap.maps.voxel_grid import SemanticVoxelGrid
    from semmap.run.outputs import refine_maps

    rng = np.random.default_rng(2)
    points = rng.uniform([-1, -1, 1], [1, 1, 2], (6000, 3)).astype(np.float32)
    sem = TopKProbs.from_hard_labels(rng.integers(0, 7, 6000).astype(np.uint16), 0.9, 7)
    m = SemanticVoxelGrid(0.02, label_set=room_label_set())
    m.integrate(Observation(points, np.zeros(3), np.full((6000, 3), 200, np.uint8), sem))
    before = m.class_probs().copy()
    with pytest.raises(MemoryBudgetError, match=r"--crf over the [0-9,]+ elements of the voxelgrid map with 7 classes "
                                                r"needs about .* over the budget of 2\.1 MB"):
        refine_map(m, CrfParams())
    out = refine_maps([m], [np.eye(4)], params=CrfParams(iterations=2), scorer=RunScorer(None, 0.02))
    assert out[m.kind]["refined"] == 0 and "--crf" in out[m.kind]["skipped"]
    assert "the voxelgrid map is not refined: --crf over" in caplog.text
    assert np.array_equal(m.class_probs(), before)


@pytest.mark.parametrize(("limit", "warns"), [(10, True), (20_000_000, False)])
def test_m3_a_view_too_fine_to_map_quickly_is_announced_before_mapping(monkeypatch, caplog, limit, warns):
    from semmap import pipeline
    from semmap.pipeline import Mapper
    from semmap.types import CameraIntrinsics

    monkeypatch.setattr(pipeline, "SLOW_VIEW_CELLS", limit)
    camera = CameraIntrinsics(64, 48, 40.0, 40.0, 31.5, 23.5)
    depth = np.full((48, 64), 2.0, np.float32)
    mapper = Mapper([SemanticOctoMap(0.1)], min_depth=0.1, max_depth=8.0)
    mapper.integrate_arrays(np.zeros((48, 64, 3), np.uint8), depth, camera, np.eye(4), index=0)
    said = "--resolution 0.1: one view spans about" in caplog.text and "(--resolution 0.2: 8x fewer)" in caplog.text
    assert said == warns
