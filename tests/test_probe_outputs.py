"""The output-side cases of the 2026-11-25 probe (issue 31: T1-T33, H2, H3, U9): a full disk, a read-only or
forbidden folder, an output of the wrong type, too long or not UTF-8, rerun onto a full disk, a garbage class prior
and an empty label folder each end in one ``semmap: error:`` line naming the file, exit code 1, no traceback, no
hang, and no input or earlier output changed.

Each case runs the command in-process through ``semmap.cli.main`` (its top-level error handling included). A full
disk is simulated (the free-space probe or ``fsync`` raising ENOSPC, as a real full disk does at the latest), a
read-only folder by ``chmod 555`` plus, as root (whom modes do not stop), an ``os.access`` that says no for it.
"""

from __future__ import annotations

import errno
import os
import stat
import sys
import threading
import time
from collections import namedtuple
from pathlib import Path

import pytest

from helpers import make_room_frames, room_label_set, write_png
from semmap.errors import OutputError
from semmap.io.tum_writer import write_tum_sequence


def _bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (or ``root`` itself) by relative path, with its bytes."""
    if root.is_file():
        return {root.name: root.read_bytes()}
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def semmap(capsys, monkeypatch, *args: str | Path) -> tuple[int, str]:
    """Run ``semmap ARGS`` in-process as the console script does; (exit code, the last stderr line) after checking
    that the failure is exactly one ``semmap: error:`` line and no traceback."""
    from semmap.cli import main

    monkeypatch.setattr(sys, "argv", ["semmap", *(os.fspath(a) for a in args)])
    with pytest.raises(SystemExit) as caught:
        main()
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err, err
    errors = [line for line in lines if line.startswith("semmap: error:")]
    assert len(errors) == 1 and lines[-1] == errors[0], err
    return caught.value.code, errors[0]


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    """A 3-frame room sequence ``seq`` and the outputs of one run over it (``run``: map.semmap, map.ot, ...)."""
    from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
    from semmap.runner import run_config

    root = tmp_path_factory.mktemp("probe")
    write_tum_sequence(root / "seq", make_room_frames(3), label_set=room_label_set())
    run_config(RunConfig(input=InputConfig(dataset=root / "seq"), mapping=MappingConfig(resolution=0.2),
                         semantics=SemanticsConfig(), output=OutputConfig(out=root / "run", plots=False)))
    return root


@pytest.fixture
def inputs(world):
    """The module's sequence and run; their bytes must not change in any case."""
    before = {name: _bytes(world / name) for name in ("seq", "run")}
    yield world
    assert {name: _bytes(world / name) for name in ("seq", "run")} == before


# ---------------------------------------------------------------------------------------------- T1-T9: full disk
_FEW_PARTICLES = ("--particles", "50", "--points", "50", "--max-frames", "2")


def _commands(w: Path, out: Path) -> dict[str, list]:
    """One command per kind of output, each writing under ``out``."""
    seq, gt, labels = w / "seq", w / "seq" / "groundtruth.txt", w / "seq" / "labels"
    return {"run": ["run", seq, "--out", out / "run", "--resolution", "0.2"],
            "track": ["track", seq, "--out", out / "t.txt", "--method", "odometry", "--plot", out / "t.png"],
            "localize": ["localize", w / "run", seq, "--out", out / "loc", *_FEW_PARTICLES],
            "train": ["train", "--model", "fcn", "--data", seq, "--out", out / "t", "--iterations", "1"],
            "eval-seg": ["eval-seg", labels, labels, "--num-classes", "7", "--out", out / "x.json"],
            "eval-traj": ["eval-traj", gt, gt, "--plot", out / "x.png"],
            "simulate": ["simulate", "--out", out / "sim", "--frames", "2"],
            "view": ["view", w / "run" / "map.ot", "--save", out / "x.rrd"],
            "run --rerun": ["run", seq, "--out", w / "elsewhere", "--rerun", out / "x.rrd"]}


@pytest.mark.slow
@pytest.mark.parametrize("command", list(_commands(Path(), Path())))
def test_t1_t9_h2_h3_a_full_disk_is_refused_before_any_work(command, inputs, tmp_path, capsys, monkeypatch):
    full = tmp_path / "full"
    full.mkdir()
    monkeypatch.setattr("semmap.files.outputs.free_bytes",
                        lambda folder: 4096 if Path(folder) == full.resolve() else 1 << 40)
    code, line = semmap(capsys, monkeypatch, *_commands(inputs, full)[command])
    assert code == 1 and "no space left on the device" in line and str(full) in line
    assert list(full.iterdir()) == [] and not (inputs / "elsewhere").exists()


def _fsync_fails(monkeypatch, after: int = 0) -> None:
    """Every ``fsync`` after the first ``after`` raises ENOSPC (what a full disk does when the data hit it)."""
    calls = iter(range(10**6))
    real = os.fsync

    def fsync(fd: int) -> None:
        if next(calls) >= after:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fd)

    monkeypatch.setattr("semmap.files.atomic.os.fsync", fsync)


@pytest.mark.parametrize("command, named", [("run", "run/map.ot"), ("track", "t.txt"), ("eval-seg", "x.json"),
                                            ("localize", "loc/localization.txt")])
def test_t1_t9_the_disk_filling_up_mid_write_names_the_file_and_keeps_the_earlier_output(
        command, named, inputs, tmp_path, capsys, monkeypatch):
    earlier = tmp_path / named
    earlier.parent.mkdir(parents=True, exist_ok=True)
    earlier.write_bytes(b"an earlier good output")
    before = _bytes(tmp_path)
    _fsync_fails(monkeypatch)
    code, line = semmap(capsys, monkeypatch, *_commands(inputs, tmp_path)[command])
    assert code == 1 and line.startswith(f"semmap: error: cannot write {tmp_path / named}: No space left on device")
    assert "free some space" in line
    assert _bytes(tmp_path) == before and not any(p.name.startswith(".") for p in tmp_path.rglob("*"))  # (staged)


def test_t3_a_checkpoint_on_a_full_disk_is_one_line(inputs, tmp_path, capsys, monkeypatch):
    _fsync_fails(monkeypatch)
    code, line = semmap(capsys, monkeypatch, "run", inputs / "seq", "--out", tmp_path / "ck", "--resolution", "0.2",
                        "--checkpoint-every", "1")
    assert code == 1 and f"cannot write {tmp_path / 'ck' / 'checkpoint.npz'}: No space left" in line
    assert not (tmp_path / "ck").exists()


@pytest.mark.parametrize("error, line", [
    ((errno.ENOSPC, "No space left on device", "full/.run.partial/map.ot"),
     "cannot write full/run/map.ot: No space left on device; free some space or write elsewhere (nothing was "
     "replaced)"),
    ((errno.EROFS, "Read-only file system", "ro/.x.png.ebc0tc02.tmp"),
     "cannot write ro/x.png: Read-only file system; write elsewhere (nothing was replaced)"),
    ((errno.EACCES, "Permission denied", "h/x.txt"),  # (a read could meet it too: no "cannot write")
     "h/x.txt: Permission denied; check the permissions, or choose another path"),
    ((errno.ENAMETOOLONG, "File name too long", "o/" + "z" * 250), "choose a shorter name")])
def test_a_refused_write_is_one_line_naming_the_output_the_user_gave(error, line):
    from semmap.files.outputs import write_failure

    assert line in str(write_failure(OSError(*error)))


def test_a_staging_folder_the_disk_refuses_is_named_and_removed(tmp_path, monkeypatch):
    from semmap.files.outputs import write_failure
    from semmap.io.staged_run import StagedRun, staging_folder

    def no_space(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", no_space)
    with pytest.raises(OSError) as caught:
        StagedRun(tmp_path / "out").open()
    assert str(write_failure(caught.value)).startswith(f"cannot write {tmp_path / 'out'}: No space left")
    assert not staging_folder(tmp_path / "out").exists()


# ---------------------------------------------------------------------------------------------- T10-T18, T26
@pytest.fixture
def read_only(tmp_path, monkeypatch) -> Path:
    """A folder mode 555 (as root, whom the mode does not stop, ``os.access`` says no for it too)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    if os.geteuid() == 0:
        real = os.access
        monkeypatch.setattr("semmap.files.outputs.os.access",
                            lambda path, mode, **kw: False if Path(path) == ro else real(path, mode, **kw))
    yield ro
    ro.chmod(0o755)


@pytest.mark.parametrize("command", ["run", "track", "localize", "train", "eval-seg", "eval-traj", "simulate",
                                    "view"])
def test_t10_t18_t26_a_read_only_folder_is_refused_before_any_work(command, inputs, read_only, capsys, monkeypatch):
    code, line = semmap(capsys, monkeypatch, *_commands(inputs, read_only)[command])
    assert code == 1 and f"cannot write in {read_only} (permission denied)" in line
    assert list(read_only.iterdir()) == []


# ---------------------------------------------------------------------------------------------- T19-T29
def test_t19_t22_an_existing_file_as_output_folder(inputs, capsys, monkeypatch):
    victim = inputs / "seq" / "rgb.txt"
    w = inputs
    for args in (["simulate", "--out", victim, "--frames", "2"],
                 ["train", "--model", "fcn", "--data", w / "seq", "--out", victim],
                 ["localize", w / "run", w / "seq", "--out", w / "run" / "report.md"],
                 ["batch", w / "seq", "--out", w / "run" / "report.md"]):
        code, line = semmap(capsys, monkeypatch, *args)
        assert code == 1 and line.endswith("is a file; give a folder") and "--out" in line, args


def test_t23_t25_t27_t28_a_folder_or_a_device_as_output_file(inputs, tmp_path, capsys, monkeypatch):
    w, folder = inputs, tmp_path
    gt, labels = w / "seq" / "groundtruth.txt", w / "seq" / "labels"
    for args, message in ((["eval-seg", labels, labels, "--num-classes", "7", "--out", folder], "is a folder"),
                          (["eval-traj", gt, gt, "--plot", folder], "is a folder"),
                          (["track", w / "seq", "--method", "odometry", "--out", folder], "is a folder"),
                          (["view", w / "run" / "map.ot", "--save", folder], "is a folder"),
                          (["view", w / "run" / "map.ot", "--save", "/dev/full"], "is a device")):
        code, line = semmap(capsys, monkeypatch, *args)
        assert code == 1 and f"{args[-2]} {args[-1]}: {message}" in line, args
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode) and list(folder.iterdir()) == []


def test_t29_t31_too_long_and_non_utf8_outputs_are_refused_before_mapping(inputs, tmp_path, capsys, monkeypatch):
    long = tmp_path / ("z" * 250)
    code, line = semmap(capsys, monkeypatch, "run", inputs / "seq", "--out", long)
    assert code == 1 and "more than the 231 an output may have" in line
    odd = Path(os.fsdecode(os.fsencode(str(tmp_path)) + b"/out_\xff\xfe"))
    code, line = semmap(capsys, monkeypatch, "run", inputs / "seq", "--out", odd)
    assert code == 1 and "--out" in line and "not UTF-8" in line
    odd_seq = Path(os.fsdecode(os.fsencode(str(tmp_path)) + b"/seq_\xff"))
    odd_seq.symlink_to(inputs / "seq")
    code, line = semmap(capsys, monkeypatch, "run", odd_seq, "--out", tmp_path / "o")
    assert code == 1 and "DATASET" in line and "not UTF-8" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == [odd_seq.name]


# ---------------------------------------------------------------------------------------------- T32, T33
def test_t32_a_class_prior_that_is_not_text(inputs, tmp_path, capsys, monkeypatch):
    garbage = tmp_path / "garbage.ot"
    garbage.write_bytes(b"\x00\x82\xe6\xff" * 50)
    code, line = semmap(capsys, monkeypatch, "run", inputs / "seq", "--out", tmp_path / "o", "--resolution", "0.2",
                        "--maps", "points", "--fusion", "bayes-prior", "--class-prior", garbage)
    assert code == 1 and f"semmap: error: {garbage}: class prior is not UTF-8 text" in line
    assert not (tmp_path / "o").exists()


def test_t33_training_images_with_an_empty_label_folder(tmp_path, capsys, monkeypatch):
    import numpy as np

    data = tmp_path / "plain"
    for i in range(3):
        write_png(data / "images" / f"{i}.png", np.full((24, 32, 3), 40 * i, np.uint8))
    (data / "labels").mkdir()
    code, line = semmap(capsys, monkeypatch, "train", "--model", "fcn", "--data", data, "--out", tmp_path / "t",
                        "--iterations", "1")
    assert code == 1 and f"{data}: none of the 3 training images has a label image" in line
    assert not (tmp_path / "t").exists()


# ---------------------------------------------------------------------------------------------- H2, H3, U9: rerun
class _StuckRecording:
    """A rerun stream whose file writer died on a full disk: flushes time out, closing blocks for ever."""

    def __init__(self, flush_error: str = "Flush timed out - not all log messages were sent") -> None:
        self.flush_error, self.release = flush_error, threading.Event()

    def flush(self, *, timeout_sec: float) -> None:
        time.sleep(min(timeout_sec, 0.01))
        raise RuntimeError(self.flush_error)

    def disconnect(self) -> None:
        self.release.wait()


@pytest.fixture
def nearly_full(monkeypatch):
    from semmap.viz import rerun_log

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(rerun_log.shutil, "disk_usage", lambda _: usage(2 << 20, 2 << 20, 4096))
    monkeypatch.setattr(rerun_log, "DISCONNECT_TIMEOUT_S", 0.2)
    dropped = []
    monkeypatch.setattr("rerun.unregister_shutdown", lambda: dropped.append(True))
    return dropped


def test_h2_h3_a_stuck_rerun_writer_fails_fast_naming_the_file(tmp_path, nearly_full):
    from semmap.viz.rerun_log import close_recording

    stuck = _StuckRecording()
    t0 = time.perf_counter()
    with pytest.raises(OutputError, match=r"cannot write the rerun recording .*x\.rrd: no space left on the device"):
        close_recording(stuck, tmp_path / ".x.rrd.partial")
    assert time.perf_counter() - t0 < 5 and nearly_full == [True]  # rerun's exit hook would wait for ever: dropped
    stuck.release.set()


def test_u9_a_dead_file_writer_is_not_called_an_unreachable_viewer(tmp_path, nearly_full):
    from semmap.viz.rerun_log import close_recording

    dead = _StuckRecording("File-writer thread shut down prematurely")
    dead.release.set()
    with pytest.raises(OutputError) as caught:
        close_recording(dead, tmp_path / "x.rrd")
    assert "viewer" not in str(caught.value) and "cannot write the rerun recording" in str(caught.value)
    with pytest.raises(Exception, match="rerun viewer unreachable"):  # only a viewer is a viewer
        close_recording(dead, None)


def test_h3_a_disk_filling_up_during_the_run_stops_the_recording_in_one_line(inputs, tmp_path, capsys, monkeypatch):
    from semmap.viz import rerun_log

    recording = tmp_path / "x.rrd"
    recording.write_bytes(b"an earlier recording")
    usage, calls = namedtuple("usage", "total used free"), []

    def disk_usage(folder):  # room when the recording starts, 1 MB left from the first frame on
        calls.append(folder)
        return usage(1 << 40, 0, 1 << 30 if len(calls) == 1 else 1 << 20)

    monkeypatch.setattr(rerun_log.shutil, "disk_usage", disk_usage)
    code, line = semmap(capsys, monkeypatch, "run", inputs / "seq", "--out", tmp_path / "o", "--resolution", "0.2",
                        "--rerun", recording)
    assert code == 1 and f"cannot write the rerun recording {recording}: only 1.0 MB free" in line
    assert recording.read_bytes() == b"an earlier recording" and sorted(p.name for p in tmp_path.iterdir()) == [
        "x.rrd"]


# ---------------------------------------------------------------------------------------------- localize: staged
def test_localize_replaces_its_folder_as_a_whole_or_not_at_all(inputs, tmp_path, capsys, monkeypatch):
    from semmap.localization.outputs import particles_png

    out = tmp_path / "loc"
    out.mkdir()
    (out / "particles.gif").write_bytes(b"from an earlier localization")
    before = _bytes(out)
    args = ["localize", inputs / "run", inputs / "seq", "--out", out, *_FEW_PARTICLES]

    def full(*a, **kw):
        raise OSError(errno.ENOSPC, "No space left on device", str(out.parent / ".loc.partial" / "particles.png"))

    monkeypatch.setattr("semmap.localization.outputs.particles_png", full)
    code, line = semmap(capsys, monkeypatch, *args)
    assert code == 1 and line.startswith(f"semmap: error: cannot write {out / 'particles.png'}: No space left")
    assert _bytes(out) == before and sorted(p.name for p in tmp_path.iterdir()) == ["loc"]
    monkeypatch.setattr("semmap.localization.outputs.particles_png", particles_png)
    from semmap.cli import main

    monkeypatch.setattr(sys, "argv", ["semmap", *map(str, args)])
    with pytest.raises(SystemExit) as caught:
        main()
    assert caught.value.code in (0, None)
    assert not (out / "particles.gif").exists() and (out / "localization.txt").is_file()  # no mix of two runs
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loc"]
