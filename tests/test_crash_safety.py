"""Crash safety: outputs appear in --out as one consistent set, a run killed with kill -9 and resumed from its
checkpoint ends with the map of an uninterrupted run (byte for byte), and Ctrl-C prints one line and exits 130."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import make_room_frames, room_label_set, run_cli
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
from semmap.errors import ConfigError
from semmap.io.staged_run import staging_folder
from semmap.io.tum_writer import write_tum_sequence
from semmap.pipeline import Pipeline
from semmap.sim.export import simulate_sequence

SCRIPT = Path(__file__).with_name("interrupt_run.py")
MAP_FILES = ("map.ot", "map.bt", "map.semmap", "trajectory.txt")
OPTIONS = ("--resolution", "0.1", "--semantics", "oracle", "--segment-every", "2")


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A short simulated sequence mapped with the oracle segmenter every second frame (state in the schedule)."""
    return simulate_sequence(tmp_path_factory.mktemp("crash") / "sim", scene_seed=3, kind="office", size="small",
                             trajectory="desk", frames=12)


@pytest.fixture(scope="module")
def uninterrupted(sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("whole") / "out"
    r = run_cli("run", str(sim), "--out", str(out), *OPTIONS)
    assert r.returncode == 0, r.stderr
    return out


def _interrupt(sig: str, at: int, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), sig, str(at), *args], capture_output=True, text=True,
                          timeout=300)


@pytest.mark.slow
def test_a_run_killed_with_kill_9_resumes_to_the_same_map(sim, uninterrupted, tmp_path):
    out = tmp_path / "out"
    r = _interrupt("KILL", 7, str(sim), "--out", str(out), *OPTIONS, "--checkpoint-every", "2")
    assert r.returncode == -9
    assert not out.exists() and (staging_folder(out) / "checkpoint.npz").is_file()  # --out untouched
    r = run_cli("run", str(sim), "--out", str(out), *OPTIONS, "--checkpoint-every", "2", "--resume")
    assert r.returncode == 0, r.stderr
    assert "resuming" in r.stderr and "after frame" in r.stderr
    for name in MAP_FILES:
        assert (out / name).read_bytes() == (uninterrupted / name).read_bytes(), name
    report, whole = (json.loads((d / "report.json").read_text()) for d in (out, uninterrupted))
    timing = {"ms_per_frame", "startup_s", "segmenter_startup_s", "peak_rss_mb", "frames_per_second"}
    assert {k: v for k, v in report.items() if k not in timing} == {k: v for k, v in whole.items() if k not in timing}
    assert not staging_folder(out).exists()


@pytest.mark.slow
def test_ctrl_c_prints_one_line_exits_130_and_writes_nothing(sim, tmp_path):
    out = tmp_path / "out"
    r = _interrupt("INT", 5, str(sim), "--out", str(out), *OPTIONS)
    assert r.returncode == 130
    lines = [line for line in r.stderr.splitlines() if line.startswith("semmap:") and "WARNING" not in line]
    assert lines == [f"semmap: interrupted after frame 5 of the sequence ({4 / 30:.6f}), 5 frames mapped; nothing "
                     "written"]
    assert "Traceback" not in r.stderr and "SystemError" not in r.stderr
    assert not out.exists() and not staging_folder(out).exists()
    r = _interrupt("INT", 5, str(sim), "--out", str(out), *OPTIONS, "--checkpoint-every", "3")
    assert r.returncode == 130 and "checkpoint kept in" in r.stderr and "--resume" in r.stderr
    assert (staging_folder(out) / "checkpoint.npz").is_file()


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("room-staging")
    write_tum_sequence(root, make_room_frames(4), label_set=room_label_set())
    return root


def _config(room: Path, out: Path) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=room), mapping=MappingConfig(resolution=0.2),
                     semantics=SemanticsConfig(), output=OutputConfig(out=out, plots=False))


def test_a_failed_write_leaves_the_earlier_run_untouched(room, tmp_path, monkeypatch):
    out = tmp_path / "out"
    Pipeline(_config(room, out)).run()
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def broken_save(path, m):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("semmap.io.native.save_map", broken_save)  # fails after map.ot and map.bt were written
    with pytest.raises(OSError):
        Pipeline(_config(room, out).model_copy(update={"mapping": MappingConfig(resolution=0.1)})).run()
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no mix of two runs
    assert not staging_folder(out).exists()


def test_a_live_run_owns_its_staging_folder_and_a_stale_one_is_cleared(room, tmp_path):
    out = tmp_path / "out"
    stage = staging_folder(out)
    stage.mkdir()
    (stage / "owner").write_text(str(os.getppid()))  # a process that is alive
    with pytest.raises(ConfigError, match="another semmap run"):
        Pipeline(_config(room, out)).run()
    (stage / "owner").write_text("999999999")  # a crashed run's leftovers
    (stage / "map.ot").write_text("half a file")
    Pipeline(_config(room, out)).run()
    assert out.is_dir() and not stage.exists() and (out / "map.ot").read_bytes()[:9] == b"# Octomap"


def test_resume_without_a_checkpoint_starts_from_the_first_frame(room, tmp_path, caplog):
    result = Pipeline(_config(room, tmp_path / "out"), resume=True).run()
    assert result.report["frames_used"] == 4 and "no checkpoint" in caplog.text
