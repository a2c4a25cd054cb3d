"""The findings of the probe of the new commands (2026-11-28, issue 48: ../shared/probes/new-surfaces-2026-11-28.md),
each rebuilt from its row on a small fixture: D1 (data loss), S1-S6 (silent wrong results), T1-T2 (tracebacks),
M1 (memory), U1-U9 (unclear messages) and the frictions of `info` / `view` with the products semmap writes.

Commands run in-process through ``semmap.cli.main`` (its one-line errors and exit codes)."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest


def semmap(capsys, monkeypatch, *args: str | Path) -> tuple[int, str, str]:
    """``semmap ARGS`` as the console script runs it: (exit code, stdout, stderr); never a traceback."""
    from semmap.cli import main

    monkeypatch.setattr(sys, "argv", ["semmap", *(os.fspath(a) for a in args)])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code or 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return code, out, err


def one_error(code: int, err: str) -> str:
    """The one ``semmap: error:`` line of a refused command (exit code 1), as the output policy asks."""
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("semmap: error:")]
    assert code == 1 and len(errors) == 1 and lines[-1] == errors[0], err
    return errors[0]


def tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    """A small simulated office (``seq``, 4 frames at 80x60) and one run over it, ``run``: an OctoMap, a point map
    and a TSDF at 10 cm, with the simulator's object instances (objects.json)."""
    from semmap.config import InputConfig, MappingConfig, ObjectsConfig, OutputConfig, RunConfig
    from semmap.maps.registry import MapKind
    from semmap.runner import run_config
    from semmap.sim.export import simulate_sequence

    root = tmp_path_factory.mktemp("probe48")
    simulate_sequence(root / "seq", frames=4, size="small", image_size=(80, 60), scene_seed=0)
    run_config(RunConfig(input=InputConfig(dataset=root / "seq"),
                         mapping=MappingConfig(resolution=0.1, maps=(MapKind.OCTOMAP, MapKind.POINTS, MapKind.TSDF)),
                         objects=ObjectsConfig(instances="oracle"),
                         output=OutputConfig(out=root / "run", cloud=False)))
    return root


# ------------------------------------------------------------------ D1: an export never replaces another kind's
@pytest.mark.slow
@pytest.mark.parametrize(("first", "second"), [
    (["export", "grid", "{run}", "--out", "{out}"], ["diff", "{run}", "{run}", "--out", "{out}"]),  # df_out_overgrid
    (["diff", "{run}", "{run}", "--out", "{out}"], ["export", "grid", "{run}", "--out", "{out}"]),  # gr_out_diffdir
    (["export", "grid", "{run}", "--out", "{out}"], ["export", "esdf", "{run}", "--out", "{out}"]),  # es_out_grid
])
def test_d1_an_export_does_not_replace_an_export_of_another_kind(world, tmp_path, capsys, monkeypatch, first,
                                                                  second):
    fill = {"run": world / "run", "out": tmp_path / "victim"}
    assert semmap(capsys, monkeypatch, *(a.format(**fill) for a in first))[0] == 0
    before = tree(tmp_path / "victim")
    line = one_error(*semmap(capsys, monkeypatch, *(a.format(**fill) for a in second))[::2])
    assert f"--out {tmp_path / 'victim'}: holds the output of semmap " in line and "nothing was written" in line
    assert tree(tmp_path / "victim") == before


def test_d1_an_export_replaces_its_own_kind_but_not_a_file_added_to_it(world, tmp_path, capsys, monkeypatch):
    out = tmp_path / "grid"
    for _ in range(2):  # the same export again: replaced whole
        assert semmap(capsys, monkeypatch, "export", "grid", world / "run", "--out", out)[0] == 0
    (out / "notes.txt").write_text("mine")
    line = one_error(*semmap(capsys, monkeypatch, "export", "grid", world / "run", "--out", out)[::2])
    assert "holds files semmap export grid did not write (notes.txt)" in line
    assert (out / "notes.txt").read_text() == "mine" and (out / "grid.json").is_file()


# ------------------------------------------------------------------ S1, T1, U1: merge --transform
def transform_file(folder: Path, name: str, rows: list[str]) -> Path:
    path = folder / name
    path.write_text("\n".join(rows) + "\n")
    return path


def translation(t: str) -> list[str]:
    return [f"1 0 0 {t}", "0 1 0 0", "0 0 1 0", "0 0 0 1"]


def strict_json(text: str):
    """JSON as a strict parser reads it: NaN and Infinity are no numbers."""
    def refuse(name: str):
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_s1_a_given_transform_that_meets_nothing_is_refused(world, tmp_path, capsys, monkeypatch):
    far = transform_file(tmp_path, "T_far.txt", translation("50"))  # mg_T_far
    line = one_error(*semmap(capsys, monkeypatch, "merge", world / "run", world / "run", "--out", tmp_path / "m",
                             "--transform", far)[::2])
    assert f"--transform {far}: it leaves 0.0 % of the smaller map's occupied voxels" in line
    assert "--min-overlap 0" in line and not (tmp_path / "m").exists()


def test_s1_min_overlap_0_merges_side_by_side_into_valid_json(world, tmp_path, capsys, monkeypatch):
    far = transform_file(tmp_path, "T_far.txt", translation("50"))
    code, _, err = semmap(capsys, monkeypatch, "merge", world / "run", world / "run", "--out", tmp_path / "m",
                          "--transform", far, "--min-overlap", "0")
    assert code == 0 and "RMSE -" in err
    summary = strict_json((tmp_path / "m" / "merge.json").read_text())
    assert summary["alignment"]["rmse_m"] is None and summary["alignment"]["overlap"] == 0.0
    occupied = summary["occupied"]
    assert occupied["merged"] == occupied["a"] + occupied["b"]


def test_t1_a_transform_out_of_the_maps_space_is_one_line(world, tmp_path, capsys, monkeypatch):
    huge = transform_file(tmp_path, "T_huge.txt", translation("1e12"))  # mg_T_huge
    for extra in ([], ["--min-overlap", "0"]):
        line = one_error(*semmap(capsys, monkeypatch, "merge", world / "run", world / "run", "--out", tmp_path / "m",
                                 "--transform", huge, *extra)[::2])
        assert f"--transform {huge}: moves " in line and "out of the space a map at 0.1 m holds" in line


def test_t1_merging_with_nothing_of_b_on_a_lattice_keeps_a():
    from semmap.products.merge import _union

    keys, ia, ib = _union(np.array([3, 5], np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    assert keys.tolist() == [3, 5] and ia.tolist() == [0, 1] and ib.tolist() == [-1, -1]


@pytest.mark.parametrize(("value", "shown"), [("nan", "'nan'"), ("inf", "'inf'"), ("-Infinity", "'-Infinity'")])
def test_u1_a_non_finite_transform_value_is_named(tmp_path, value, shown):
    from semmap.errors import FormatError
    from semmap.products.merge import read_transform

    path = transform_file(tmp_path, "T.txt", ["1 0 0 0", f"0 1 0 {value}", "0 0 1 0", "0 0 0 1"])  # mg_T_nan
    with pytest.raises(FormatError, match=f"row 2 holds {shown}$"):
        read_transform(path)
    with pytest.raises(FormatError, match=r"got 4 \+ 4 \+ 3 numbers in 3 rows"):
        read_transform(transform_file(tmp_path, "T3.txt", ["1 0 0 0", "0 1 0 0", "0 0 1"]))


# ------------------------------------------------------------------ S2: eval-map --gt-ply in another frame
def labelled_ply(path: Path, points: np.ndarray, labels: np.ndarray) -> Path:
    """Binary PLY of labelled vertices (x y z float, label ushort), as ScanNet's ground truth keeps them."""
    rows = np.zeros(len(points), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<u2")])
    rows["x"], rows["y"], rows["z"] = np.asarray(points).T
    rows["label"] = labels
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(points)}", "property float x",
              "property float y", "property float z", "property ushort label", "end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + rows.tobytes())
    return path


@pytest.fixture(scope="module")
def truth(world) -> tuple[np.ndarray, np.ndarray]:
    """The map's own occupied voxel centres and classes (a ground truth the map meets everywhere)."""
    from semmap.io.map_files import load_map
    from semmap.types import EMPTY_LABEL

    cloud = load_map(world / "run" / "map.semmap").cloud()
    keep = (cloud.labels != EMPTY_LABEL) & (cloud.labels != 0)
    return cloud.centers[keep], cloud.labels[keep]


def test_s2_ground_truth_in_another_frame_is_refused(world, truth, tmp_path, capsys, monkeypatch):
    far = labelled_ply(tmp_path / "gt_far.ply", truth[0] + [100.0, 0.0, 0.0], truth[1])  # em_far
    line = one_error(*semmap(capsys, monkeypatch, "eval-map", world / "run", "--gt-ply", far)[::2])
    assert f"{far}: 100.0 % of its labelled points lie farther than a voxel diagonal" in line
    assert "ground truth x 10" in line and "is it in the map's frame and in metres?" in line


def test_s2_ground_truth_the_map_meets_is_scored_and_half_of_it_warned(world, truth, tmp_path, capsys,
                                                                        monkeypatch):
    same = labelled_ply(tmp_path / "gt.ply", *truth)
    code, out, err = semmap(capsys, monkeypatch, "eval-map", world / "run", "--gt-ply", same)
    assert code == 0 and json.loads(out)["points_miou"] > 0.9 and "warning" not in err
    n = len(truth[0])
    shifted = truth[0] + np.where(np.arange(n)[:, None] < 0.7 * n, [100.0, 0.0, 0.0], 0.0)
    code, out, err = semmap(capsys, monkeypatch, "eval-map", world / "run", "--gt-ply",
                            labelled_ply(tmp_path / "gt_part.ply", shifted, truth[1]))
    assert code == 0 and "% of the labelled points lie farther than a voxel diagonal from the map" in err


# ------------------------------------------------------------------ S3: scene-graph and the run's sequence
def run_copy(world: Path, where: Path, config_text: str | None) -> Path:
    """A copy of the run folder whose config.json is ``config_text`` (None: as it is)."""
    shutil.copytree(world / "run", where)
    if config_text is not None:
        (where / "config.json").write_text(config_text)
    return where


def relative_config(world: Path, dataset: str, out: str) -> str:
    config = json.loads((world / "run" / "config.json").read_text())
    config["input"]["dataset"], config["output"]["out"] = dataset, out
    return json.dumps(config)


def test_s3_a_relative_sequence_is_found_from_another_folder(world, tmp_path, capsys, monkeypatch):
    (tmp_path / "proj").mkdir()
    (tmp_path / "proj" / "sim").mkdir()
    (tmp_path / "proj" / "sim" / "a").symlink_to(world / "seq")
    run_copy(world, tmp_path / "proj" / "runs" / "a", relative_config(world, "sim/a", "runs/a"))
    (tmp_path / "proj" / "o").mkdir()
    monkeypatch.chdir(tmp_path / "proj" / "o")  # sg_from_cwd: cd o && semmap export scene-graph ../runs/a
    code, out, err = semmap(capsys, monkeypatch, "export", "scene-graph", "../runs/a", "--out", "sg_cwd")
    assert code == 0 and "(from the layout)" in out and "warning" not in err.lower(), out + err


@pytest.mark.parametrize(("case", "config_text", "said"), [
    ("sg_cfg_missing", "missing", "names the sequence /nowhere/seq, which is not there"),
    ("sg_badcfg", "{garbage", "names no sequence (JSONDecodeError"),
])
def test_s3_a_sequence_that_cannot_be_found_is_said(world, tmp_path, capsys, monkeypatch, case, config_text, said):
    text = relative_config(world, "/nowhere/seq", "/nowhere/run") if config_text == "missing" else config_text
    run = run_copy(world, tmp_path / case, text)
    code, out, err = semmap(capsys, monkeypatch, "export", "scene-graph", run, "--out", tmp_path / "sg")
    assert code == 0 and "(from the grid)" in out
    assert f"{run / 'config.json'} {said}" in err and "rooms come from a segmentation of the map's grid" in err


def test_s3_a_grid_without_rooms_is_said(world, tmp_path, capsys, monkeypatch):
    plain = tmp_path / "plain"  # sg_nosim: --sequence of a recording that is not simulated
    shutil.copytree(world / "seq", plain)
    (plain / "scene.json").unlink()
    code, out, err = semmap(capsys, monkeypatch, "export", "scene-graph", world / "run", "--out", tmp_path / "sg",
                            "--sequence", plain, "--door-width", "9")
    assert code == 0 and "0 rooms (from the grid)" in out
    assert "found no room (no free cell lies 4.5 m, half of --door-width, from every obstacle" in err


# ------------------------------------------------------------------ S4: a grid of a map without free space
@pytest.mark.parametrize("name", ["points.semmap", "tsdf.semmap"])  # gr_points, gr_tsdf
def test_s4_a_grid_without_free_space_is_said(world, tmp_path, capsys, monkeypatch, name):
    code, out, err = semmap(capsys, monkeypatch, "export", "grid", world / "run" / name, "--out", tmp_path / "g")
    assert code == 0 and "free 0," in out
    assert "map keeps no free space, so the grid has no free cell" in err and "--free-space" in err


def test_s4_an_octomap_grid_has_free_cells_and_no_warning(world, tmp_path, capsys, monkeypatch):
    code, out, err = semmap(capsys, monkeypatch, "export", "grid", world / "run", "--out", tmp_path / "g")
    assert code == 0 and "free 0," not in out and "warning" not in err.lower()


# ------------------------------------------------------------------ S5, U5: options that would do nothing
@pytest.mark.parametrize(("case", "args", "said"), [
    ("sg_cm_no_seg", ["--class-map", "nyu40"],
     "--class-map acts on the user's own model (onnx:MODEL, hf:MODEL); no --segmenter is given"),
    ("crfp_nocrf", ["--crf-params", "iterations=3"], "--crf-params sets the dense CRF, which runs only with --crf"),
    ("crf_every_nocrf", ["--crf-every", "3"], "--crf-every sets the dense CRF, which runs only with --crf"),
    ("dyn_semnone", ["--semantics", "none", "--dynamic", "chair"],
     "--dynamic chair: the run has no classes (--semantics none), so no point is of a dynamic class"),
    ("decay_pts", ["--maps", "points", "--decay", "0.5"],
     "--decay acts on the OctoMap and a voxel grid's free space (--free-space); --maps points has neither"),
])
def test_s5_an_option_that_would_be_ignored_is_refused(world, tmp_path, capsys, monkeypatch, case, args, said):
    line = one_error(*semmap(capsys, monkeypatch, "run", world / "seq", "--out", tmp_path / "o", "--max-frames", "1",
                             "--no-cloud", *args)[::2])
    assert line == f"semmap: error: {said}" or line.startswith(f"semmap: error: {said}")
    assert not (tmp_path / "o").exists()


def test_s5_the_rules_leave_what_they_do_not_name_alone():
    from semmap.config import MappingConfig, SemanticsConfig
    from semmap.maps.registry import MapKind

    MappingConfig(maps=(MapKind.VOXELGRID,), free_space=True, decay=0.5)
    MappingConfig(maps=(MapKind.POINTS, MapKind.OCTOMAP), decay=0.5)
    SemanticsConfig(segmenter="onnx:model.onnx", class_map=Path("nyu40"))


def test_s5_train_refuses_an_architecture_init_replaces(tmp_path):
    from semmap.errors import ConfigError
    from semmap.train.trainer import TrainSettings

    def settings(**kw) -> TrainSettings:
        return TrainSettings(model="fcn", data=(tmp_path,), out=tmp_path / "o", **kw)

    # tr_init_backbone_conflict
    with pytest.raises(ConfigError, match=r"^--backbone vgg16 conflicts with --init espnetv2-pascal-s2, which sets "
                                          r"--backbone espnetv2-s2; leave --backbone out$"):
        settings(init="espnetv2-pascal-s2", backbone="vgg16").with_init()
    with pytest.raises(ConfigError, match=r"^--resnet-depth 34 conflicts with --init torchvision:resnet18"):
        settings(init="torchvision:resnet18", depth=34).with_init()
    assert settings(init="espnetv2-pascal-s2", backbone="espnetv2-s2").with_init().backbone == "espnetv2-s2"
    assert settings(init="torchvision:resnet18").with_init().width == 1.0


def test_u5_every_class_dynamic_is_refused_naming_dynamic(world, tmp_path, capsys, monkeypatch):
    from semmap.labels import INDOOR_LABELS

    every = ",".join(INDOOR_LABELS.names[1:])  # dyn_all
    line = one_error(*semmap(capsys, monkeypatch, "run", world / "seq", "--out", tmp_path / "o", "--max-frames", "1",
                             "--no-cloud", "--dynamic", every)[::2])
    assert "--dynamic names every class of the run's label set" in line and "poses" not in line
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------ S6, U6: the ESDF's slice and empty regions
@pytest.mark.slow
def test_s6_a_slice_height_outside_the_field_is_refused(world, tmp_path, capsys, monkeypatch):
    line = one_error(*semmap(capsys, monkeypatch, "export", "esdf", world / "run", "--out", tmp_path / "e",
                             "--slice-z", "1000")[::2])  # es_slice_far
    assert "--slice-z 1000: outside the field, which spans z " in line and not (tmp_path / "e").exists()
    code, _, _ = semmap(capsys, monkeypatch, "export", "esdf", world / "run", "--out", tmp_path / "e",
                        "--slice-z", "0.5")
    assert code == 0 and json.loads((tmp_path / "e" / "esdf.json").read_text())["slice_z"] == pytest.approx(0.5,
                                                                                                           abs=0.1)


@pytest.mark.slow
def test_u6_a_region_without_obstacles_says_so(world, tmp_path, capsys, monkeypatch):
    code, out, _ = semmap(capsys, monkeypatch, "export", "esdf", world / "run", "--out", tmp_path / "e",
                          "--region", "50 50 0 51 51 1")  # es_region_empty
    assert code == 0 and "largest distance none: the region holds no obstacle or no free voxel" in out
    assert "None" not in out


# ------------------------------------------------------------------ T2: scripts/calibrate_weights.py
ROOT = Path(__file__).resolve().parents[1]


def script_main(capsys, name: str, argv: list[str | Path]) -> tuple[int, str]:
    """``scripts/NAME.py ARGV`` in-process, under the wrapper its ``__main__`` uses: (exit code, stderr)."""
    from script_modules import load_script
    from semmap.cli.terminal import exit_on_errors

    module = load_script(f"scripts/{name}.py")
    with pytest.raises(SystemExit) as caught:
        exit_on_errors(lambda: module.main([os.fspath(a) for a in argv]), name)
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return caught.value.code, err


@pytest.mark.parametrize(("case", "argv", "said"), [
    ("cal_out_eq_in", ["--weights", "{w}", "--val", "{seq}", "--out", "{w}"], "--out {w}: is the input --weights"),
    ("cal_garbage", ["--weights", "{txt}", "--val", "{seq}", "--out", "{tmp}/c.pt"], "{txt}: "),
    ("cal_emptyval", ["--weights", "{w}", "--val", "{empty}", "--out", "{tmp}/c.pt"], "{empty}: "),
    ("cal_devfull", ["--weights", "{w}", "--val", "{seq}", "--out", "/dev/full"], "--out /dev/full: is a device"),
])
def test_t2_calibrate_weights_errors_are_one_line(world, tmp_path, capsys, case, argv, said):
    (tmp_path / "empty").mkdir()
    (tmp_path / "T.txt").write_text("1 0 0 0\n")
    fill = {"w": ROOT / "weights" / "fcn.pt", "seq": world / "seq", "txt": tmp_path / "T.txt",
            "empty": tmp_path / "empty", "tmp": tmp_path}
    code, err = script_main(capsys, "calibrate_weights", [a.format(**fill) for a in argv])
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 1 and len(lines) == 1 and lines[0].startswith(f"calibrate_weights: error: {said.format(**fill)}")
    assert not (tmp_path / "c.pt").exists()


def test_t2_the_user_scripts_run_under_the_wrapper():
    for name in ("calibrate_7scenes_color", "calibrate_weights", "make_training_data", "map_views", "objects_picture",
                 "segmentation_grid", "ship_weights"):
        tail = (ROOT / "scripts" / f"{name}.py").read_text().rsplit('if __name__ == "__main__":', 1)[1]
        assert f'exit_on_errors(main, "{name}")' in tail, name


# ------------------------------------------------------------------ U8: Ctrl-C in any command is one line
def test_u8_ctrl_c_in_a_command_without_its_own_handler_says_so(world, tmp_path, capsys, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("semmap.products.merge.merge_map_files", interrupted)  # int_merge
    code, _, err = semmap(capsys, monkeypatch, "merge", world / "run", world / "run", "--out", tmp_path / "m")
    assert code == 130 and err.strip().splitlines()[-1] == "semmap: interrupted"
    monkeypatch.setattr("semmap.products.export.export_esdf", interrupted)  # int_esdf
    code, _, err = semmap(capsys, monkeypatch, "export", "esdf", world / "run", "--out", tmp_path / "e")
    assert code == 130 and err.strip().splitlines()[-1] == "semmap: interrupted"


# ------------------------------------------------------------------ U7: Ctrl-C names the frame by its place
def test_u7_a_frame_is_named_by_its_place_and_its_timestamp():
    from semmap.pipeline import frame_words

    assert frame_words(40, "1.333333") == "frame 41 of the sequence (1.333333)"  # ct_doc_ctrlc
    assert frame_words(3, "3") == frame_words(3, None) == "frame 4 of the sequence"


# ------------------------------------------------------------------ U2: --min-weight has one range
@pytest.mark.parametrize("value", ["0", "1000000"])  # me_minw_0, me_minw_huge
def test_u2_min_weight_is_refused_with_one_range(world, tmp_path, capsys, monkeypatch, value):
    line = one_error(*semmap(capsys, monkeypatch, "export", "mesh", world / "run", "--out", tmp_path / "m",
                             "--min-weight", value)[::2])
    assert line.startswith("semmap: error: --min-weight must be a whole number from 1 to 10,000")


def test_u2_the_limit_is_where_a_voxel_weight_stops():
    from semmap.errors import ConfigError
    from semmap.limits import LIMITS
    from semmap.maps.tsdf import MAX_WEIGHT
    from semmap.products.export import export_mesh

    assert LIMITS["tsdf_weight"].hi == MAX_WEIGHT
    with pytest.raises(ConfigError, match="--min-weight must be a whole number from 1 to 10,000"):
        export_mesh(Path("/nonexistent"), Path("/nonexistent/out"), min_weight=10_001)


# ------------------------------------------------------------------ U3: eval-map with an .ot or a mesh
@pytest.mark.parametrize("name", ["map.ot", "mesh.ply"])  # em_map_ot, em_map_mesh
def test_u3_eval_map_says_which_file_to_give(world, truth, tmp_path, capsys, monkeypatch, name):
    gt = labelled_ply(tmp_path / "gt.ply", *truth)
    line = one_error(*semmap(capsys, monkeypatch, "eval-map", world / "run" / name, "--gt-ply", gt)[::2])
    assert f"{world / 'run' / name}: a {Path(name).suffix} file is not one of semmap's lossless maps" in line
    assert "give the .semmap file beside it" in line and "corrupt" not in line


# ------------------------------------------------------------------ U4: onnx:MODEL that is no model
def test_u4_a_missing_or_foreign_onnx_model_is_named_as_the_model(world, tmp_path, capsys, monkeypatch):
    for model, said in ((tmp_path / "nothere.onnx", "does not exist"),  # sg_onnx_missing
                        (world / "run" / "map.semmap", "ONNX Runtime cannot open it as a model")):  # sg_onnx_semmapfile
        line = one_error(*semmap(capsys, monkeypatch, "run", world / "seq", "--out", tmp_path / "o", "--max-frames",
                                 "1", "--no-cloud", "--segmenter", f"onnx:{model}")[::2])
        assert line.startswith(f"semmap: error: {model}: ") and said in line and "sidecar" not in line, line


# ------------------------------------------------------------------ M1: localize in a point map
def test_m1_a_point_map_prior_pools_its_points_into_coarser_cells(world):
    from semmap.io.map_files import load_map
    from semmap.localization.prior import POINT_PRIOR_CELL_M, load_prior

    points = load_prior(world / "run" / "points.semmap")  # lo_points: its lookup grids at 5 cm, not at 1 cm
    octomap = load_prior(world / "run" / "map.semmap")
    assert load_map(world / "run" / "points.semmap").resolution < POINT_PRIOR_CELL_M == points.resolution
    cells = int(np.prod(points.shape))
    assert cells < 2 * int(np.prod(octomap.shape)) * (octomap.resolution / points.resolution) ** 3
    assert points.class_probs is not None and np.allclose(points.class_probs.sum(axis=1), 1.0, atol=1e-3)


def test_m1_pooled_cells_average_the_points_classes():
    from semmap.localization.prior import pooled_cells

    pts = np.array([[0.01, 0.01, 0.01], [0.04, 0.02, 0.03], [0.06, 0.0, 0.0]])
    probs = np.array([[1.0, 0.0], [0.0, 1.0], [0.25, 0.75]], np.float32)
    centers, pooled = pooled_cells(pts, probs, 0.05)
    assert np.allclose(centers, [[0.025, 0.025, 0.025], [0.075, 0.025, 0.025]])
    assert np.allclose(pooled, [[0.5, 0.5], [0.25, 0.75]])
    assert pooled_cells(np.zeros((0, 3)), None, 0.05)[0].shape == (0, 3)


# ------------------------------------------------------------------ U9 and the frictions: info and view of products
@pytest.fixture(scope="module")
def products(world, tmp_path_factory) -> Path:
    """Every product semmap writes from the fixture run: grid, ESDF, mesh, scene graph, diff, merge."""
    from semmap.products.export import export_diff, export_esdf, export_grid, export_mesh, export_scene_graph
    from semmap.products.merge import merge_map_files
    from semmap.products.navgrid import GridOptions

    root = tmp_path_factory.mktemp("products")
    run = world / "run"
    export_grid(run, root / "grid", GridOptions(costs={"wall": 50}))
    export_esdf(run, root / "esdf")
    export_mesh(run, root / "mesh")
    export_scene_graph(run, root / "sg")
    export_diff(run, run, root / "diff")
    merge_map_files(run, run, root / "merge")
    return root


#: file -> (kind `info` says, what `view` counts, an entity `view` logs)
PRODUCT_FILES = {
    "mesh/mesh.ply": ("mesh", "mesh vertices", "/world/mesh"),  # info_mesh, view_mesh (U9)
    "grid/map.yaml": ("map_server grid", "grid cells", "/world/grid"),
    "grid/map.pgm": ("map_server grid", "grid cells", "/grid"),
    "grid/costmap.png": ("map_server grid", "grid cells", "/world/grid"),
    "grid/costmap.npy": ("costmap", "grid cells", "/world/grid"),
    "grid/grid.json": ("grid summary", "grid cells", "/world/grid"),
    "esdf/esdf.npz": ("esdf", "ESDF voxels", "/world/esdf"),
    "esdf/esdf.json": ("esdf summary", "ESDF voxels", "/world/esdf"),
    "esdf/esdf_slice.png": ("image", "pixels", "/image"),
    "sg/scene_graph.json": ("scene graph", "scene graph nodes", "/world/rooms"),
    "sg/graph.json": ("scene graph summary", "scene graph nodes", "/world/rooms"),
    "diff/diff.json": ("diff", "changed voxels", "/world/diff"),
    "mesh/mesh.json": ("mesh summary", "mesh vertices", "/world/mesh"),
}


def _entities(path: Path) -> set[str]:
    from rerun.chunk import RrdReader

    return {str(chunk.entity_path) for chunk in RrdReader(path).stream()}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(PRODUCT_FILES))
def test_info_and_view_open_every_product(products, tmp_path, capsys, monkeypatch, name):
    kind, counted, entity = PRODUCT_FILES[name]
    code, out, err = semmap(capsys, monkeypatch, "info", products / name)
    assert code == 0 and json.loads(out)["kind"] == kind, err
    code, _, err = semmap(capsys, monkeypatch, "view", products / name, "--save", tmp_path / "v.rrd")
    assert code == 0 and f" {counted} written to " in " ".join(err.split()), err  # (rich wraps the line)
    assert entity in _entities(tmp_path / "v.rrd")


def test_info_reads_the_mesh_it_wrote(world, products):
    from semmap.io.map_info import describe_map_file
    from semmap.io.mesh_ply import read_mesh_ply

    mesh = read_mesh_ply(products / "mesh" / "mesh.ply")
    summary = json.loads((products / "mesh" / "mesh.json").read_text())
    assert (len(mesh), len(mesh.faces)) == (summary["vertices"], summary["faces"])
    assert mesh.faces.max() < len(mesh) and mesh.label_set is not None
    info = describe_map_file(products / "mesh" / "mesh.ply")
    assert info["triangles"] == summary["faces"] and sum(info["vertices_per_class"].values()) <= len(mesh)


@pytest.mark.parametrize(("name", "kind"), [("run/objects.json", "objects"), ("run/trajectory.txt", "trajectory"),
                                            ("run/report.json", "run report"), ("run/config.json",
                                                                                "run configuration")])
def test_info_describes_a_runs_records(world, capsys, monkeypatch, name, kind):
    code, out, err = semmap(capsys, monkeypatch, "info", world / name)
    assert code == 0 and json.loads(out)["kind"] == kind, err


def test_info_of_a_merge_and_its_transform(products, capsys, monkeypatch):
    code, out, _ = semmap(capsys, monkeypatch, "info", products / "merge" / "merge.json")
    assert code == 0 and json.loads(out)["kind"] == "merge summary" and json.loads(out)["map_kind"] == "octomap"
    code, out, _ = semmap(capsys, monkeypatch, "info", products / "merge" / "transform.txt")
    assert code == 0 and json.loads(out) == {"kind": "transform", "translation_m": [0.0, 0.0, 0.0],
                                             "rotation_deg": 0.0}


def test_info_refuses_what_semmap_does_not_write_in_one_line(tmp_path, capsys, monkeypatch):
    (tmp_path / "notes.json").write_text("{}")
    (tmp_path / "x.docx").write_text("x")
    for name in ("notes.json", "x.docx"):
        line = one_error(*semmap(capsys, monkeypatch, "info", tmp_path / name)[::2])
        assert f"{tmp_path / name}: " in line and "semmap info opens" in line


# ------------------------------------------------------------------ torchvision: an extra, not a dependency
def test_torchvision_is_an_extra_so_transformers_models_load():
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not any(d.startswith("torchvision") for d in project["dependencies"])
    assert project["optional-dependencies"]["maskrcnn"] == ["torchvision==0.28.0"]
    assert "semmap[maskrcnn]" not in project["optional-dependencies"]["dev"]  # the project's own venv has none


@pytest.mark.parametrize(("call", "said"), [
    (lambda: __import__("semmap.perception.instances.maskrcnn", fromlist=["x"]).build_maskrcnn(3),
     "--instances maskrcnn needs torchvision"),
    (lambda: __import__("semmap.perception.networks.pretrained", fromlist=["x"]).torchvision_state_dict("resnet18"),
     "--init torchvision:resnet18 needs torchvision"),
])
def test_without_torchvision_its_features_say_what_to_install(monkeypatch, call, said):
    import importlib.util

    from semmap.errors import ConfigError

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "torchvision" else
                        real(name, *a))
    monkeypatch.delitem(sys.modules, "torchvision.ops", raising=False)
    with pytest.raises(ConfigError) as err:
        call()
    assert str(err.value).startswith(said) and "pip install 'semmap[maskrcnn]'" in str(err.value)
    assert "\n" not in str(err.value)


def test_hf_segmenters_do_without_torchvision(monkeypatch):
    import importlib.util

    from semmap.perception import hf_models

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "torchvision" else
                        real(name, *a))
    monkeypatch.delitem(sys.modules, "torchvision.ops", raising=False)
    assert hf_models._transformers().__name__ == "transformers"


# ------------------------------------------------------------------ the harness's NO-NAME rows of the re-run
@pytest.mark.parametrize(("region", "said"), [
    ("-1000 -1000 -10 1000 1000 10", "semmap: error: --region: a product volume of"),  # gr_region_huge
    ("50 50 0 51 51 1", "within --region, when one is given) has no occupied voxel to find the floor on"),
])
def test_a_refused_region_names_region(world, tmp_path, capsys, monkeypatch, region, said):
    line = one_error(*semmap(capsys, monkeypatch, "export", "grid", world / "run", "--out", tmp_path / "g",
                             "--region", region)[::2])
    assert said in line and not (tmp_path / "g").exists()
