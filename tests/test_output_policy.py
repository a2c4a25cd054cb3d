"""One output policy for every command (issue 31, cases D1-D12 of the 2026-11-25 probe): an output that is, contains
or lies inside an input is refused in one line before any work, only regular files and folders are replaced, and
`simulate` writes its folder atomically (a failure or Ctrl-C leaves nothing)."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

import pytest

from helpers import ROOM_CAMERA, make_room_frames, room_label_set, run_cli
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
from semmap.errors import OutputError
from semmap.files.atomic import write_bytes_atomic
from semmap.files.outputs import OutputKind, check_outputs, write_failure
from semmap.io.staged_run import staging_folder
from semmap.io.tum_writer import write_tum_sequence
from semmap.runner import evaluate_trajectories, run_config, track_to_file


def _bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (or ``root`` itself) by relative path, with its bytes."""
    if root.is_file():
        return {root.name: root.read_bytes()}
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def seq(tmp_path) -> Path:
    """A 3-frame TUM sequence inside its own parent folder ``par/``."""
    root = tmp_path / "par" / "seq"
    write_tum_sequence(root, make_room_frames(3), label_set=room_label_set())
    return root


def _config(seq: Path, out: Path, **output) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=seq), mapping=MappingConfig(resolution=0.2),
                     semantics=SemanticsConfig(), output=OutputConfig(out=out, plots=False, preview=False, **output))


def test_d1_run_out_is_the_input(seq):
    before = _bytes(seq)
    with pytest.raises(OutputError, match=r"--out .*is the input DATASET"):
        run_config(_config(seq, seq))
    assert _bytes(seq) == before and not staging_folder(seq).exists()


def test_d2_run_out_contains_the_input(seq):
    before = _bytes(seq)
    with pytest.raises(OutputError, match=r"--out .*contains the input DATASET"):
        run_config(_config(seq, seq.parent))
    assert _bytes(seq) == before


def test_d3_rerun_inside_out_survives_the_commit(seq, tmp_path):
    out = tmp_path / "rr"
    out.mkdir()
    (out / "old.txt").write_text("an earlier run")
    result = run_config(_config(seq, out, rerun=out / "run.rrd"))
    assert (out / "run.rrd").stat().st_size > 1000, "the recording moved into --out with the other files"
    assert not (out / "old.txt").exists() and (out / "map.ot").is_file() and result.out_dir == out
    assert not staging_folder(out).exists()


def test_d4_view_save_over_its_map(tmp_path):
    from semmap.viz.rerun_log import view_map

    victim = tmp_path / "victim.ot"
    victim.write_bytes(b"an OctoMap")
    with pytest.raises(OutputError, match=r"--save .*is the input MAP"):
        view_map(victim, save=victim, spawn=False)
    assert victim.read_bytes() == b"an OctoMap"


def test_d5_plot_onto_a_device_is_refused(seq):
    gt = seq / "groundtruth.txt"
    with pytest.raises(OutputError, match=r"--plot /dev/full: is a device, not a regular file"):
        evaluate_trajectories(gt, [gt], plot=Path("/dev/full"))
    with pytest.raises(OutputError, match="not a regular file"):  # the bottom layer refuses it too
        write_bytes_atomic("/dev/full", b"png")
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


def test_d6_track_out_over_the_ground_truth(seq):
    before = _bytes(seq)
    with pytest.raises(OutputError, match=r"--out .*lies inside the input DATASET"):
        track_to_file(seq, "odometry", seq / "groundtruth.txt")
    assert _bytes(seq) == before


def test_d7_rerun_over_the_ground_truth(seq, tmp_path):
    before = _bytes(seq)
    with pytest.raises(OutputError, match=r"--rerun .*lies inside the input DATASET"):
        run_config(_config(seq, tmp_path / "out", rerun=seq / "groundtruth.txt"))
    assert _bytes(seq) == before and not (tmp_path / "out").exists()


def test_d8_eval_seg_out_over_a_ground_truth_image(seq):
    from semmap.eval.segmentation import evaluate_label_folders

    labels = seq / "labels"
    target = next(labels.iterdir())
    before = _bytes(labels)
    with pytest.raises(OutputError, match=r"--out .*lies inside the input GT_DIR"):
        evaluate_label_folders(seq / "instances", labels, 7, out=target)
    assert _bytes(labels) == before


def _simulate(out: Path, **kwargs) -> Path:
    from semmap.sim.export import simulate_sequence

    return simulate_sequence(out, frames=2, size="small", intrinsics=ROOM_CAMERA, noise=False, **kwargs)


def test_d9_d10_simulate_never_mixes_into_another_folder(seq, tmp_path):
    before = _bytes(seq)
    with pytest.raises(OutputError, match=r"--out .*holds other files"):  # D9: a sequence not written by simulate
        _simulate(seq)
    assert _bytes(seq) == before
    run = tmp_path / "run"
    run.mkdir()
    (run / "map.ot").write_bytes(b"map")
    (run / "report.md").write_text("# report")
    with pytest.raises(OutputError, match=r"--out .*holds other files"):  # D10: a finished run
        _simulate(run)
    assert _bytes(run) == {"map.ot": b"map", "report.md": b"# report"}


@pytest.mark.slow
def test_d9_an_earlier_simulation_is_replaced_as_a_whole(tmp_path):
    out = _simulate(tmp_path / "sim", scene_seed=1)
    (out / "rgb" / "stale.png").write_bytes(b"from the other scene")
    _simulate(out, scene_seed=2)
    assert not (out / "rgb" / "stale.png").exists() and len(list((out / "rgb").iterdir())) == 2
    assert not staging_folder(out).exists()


@pytest.mark.slow
@pytest.mark.parametrize("failure", [KeyboardInterrupt(), OSError(errno.ENOSPC, "No space left on device")])
def test_d11_d12_an_interrupted_or_failed_simulation_leaves_nothing(tmp_path, failure):
    def progress(i: int, n: int) -> None:
        if i == 1:
            raise failure

    with pytest.raises(type(failure)) as caught:
        _simulate(tmp_path / "sim", progress=progress)
    assert list(tmp_path.iterdir()) == []  # neither the folder nor its staging folder
    assert "nothing written" in str(caught.value) or isinstance(failure, OSError)


def test_wrong_type_too_long_and_non_utf8_outputs_are_one_line(tmp_path, seq):
    folder, file = tmp_path / "folder", tmp_path / "file.txt"
    folder.mkdir()
    file.write_text("x")
    cases = [(("--out", folder, OutputKind.FILE), "is a folder; give a file name"),
             (("--out", file, OutputKind.FOLDER), "is a file; give a folder"),
             (("--out", file / "below", OutputKind.FOLDER), "lies below .*which is a file"),
             (("--out", tmp_path / ("z" * 250), OutputKind.FOLDER), "more than the 231 an output may have"),
             (("--out", Path(os.fsdecode(b"out_\xff\xfe")), OutputKind.FOLDER), "not UTF-8 text"),
             (("--plot", Path("/dev/null"), OutputKind.FILE), "is a device")]
    for output, message in cases:
        with pytest.raises(OutputError, match=message):
            check_outputs([output], [])
    with pytest.raises(OutputError, match="--out and --rerun name the same path"):
        check_outputs([("--out", tmp_path / "o", OutputKind.FOLDER), ("--rerun", tmp_path / "o", OutputKind.FILE)],
                      [])


def test_read_only_and_full_disk_are_one_line(tmp_path, monkeypatch):
    error = write_failure(OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "x")))
    assert isinstance(error, OutputError) and str(error) == (f"cannot write {tmp_path / 'x'}: No space left on device; "
                                                             f"free some space or write elsewhere")
    assert write_failure(OSError(errno.EROFS, "Read-only file system", "ro/x")) is not None
    assert write_failure(OSError(errno.EBADF, "Bad file descriptor")) is None  # a bug stays a traceback
    monkeypatch.setattr("semmap.files.outputs.os.access", lambda path, mode: False)
    with pytest.raises(OutputError, match=r"--out .*cannot write in"):
        check_outputs([("--out", tmp_path / "new", OutputKind.FOLDER)], [])


def test_localize_train_and_batch_refuse_an_input_as_output(seq):
    from semmap.batch import plan
    from semmap.localization.sequence import LocalizeOptions, localize_sequence
    from semmap.train.trainer import Trainer, TrainSettings

    before = _bytes(seq)
    with pytest.raises(OutputError, match=r"--out .*is the input SEQ"):
        localize_sequence(seq.parent / "map.semmap", seq, seq, LocalizeOptions())
    with pytest.raises(OutputError, match=r"--out .*contains the input --data"):
        Trainer(TrainSettings(model="fcn", data=(seq,), out=seq.parent))
    with pytest.raises(OutputError, match=r"--out .*is the input DATASET"):
        plan([seq], seq)
    assert _bytes(seq) == before


@pytest.mark.slow
def test_cli_refusals_are_one_line_with_exit_code_1(seq):
    before = _bytes(seq)
    r = run_cli("run", str(seq), "--out", str(seq))
    assert r.returncode == 1 and r.stderr.strip().splitlines()[-1].startswith("semmap: error: --out ")
    assert "Traceback" not in r.stderr and _bytes(seq) == before
    gt = str(seq / "groundtruth.txt")
    r = run_cli("eval-traj", gt, gt, "--plot", "/dev/full")
    assert r.returncode == 1 and "semmap: error: --plot /dev/full: is a device" in r.stderr
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


def test_a_symlink_loop_as_input_is_not_a_traceback(tmp_path):
    """Probe case in_symloop: resolving an input that is a link loop must not raise from pathlib."""
    from semmap.files.outputs import OutputKind, check_outputs

    loop = tmp_path / "seqloop"
    loop.symlink_to(loop)
    check_outputs([("--out", tmp_path / "out", OutputKind.FOLDER)], [("DATASET", loop)])  # nothing to refuse
