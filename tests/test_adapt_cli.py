"""semmap adapt and semmap run --adapt from the command line: the loop of mapping, adapting and mapping again on a
tiny simulated scene, the adapted weights reused with --weights, and one line for a run it cannot adapt."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from semmap.cli import app
from semmap.config import InputConfig, OutputConfig, RunConfig, SemanticsConfig
from semmap.errors import ConfigError, SemmapError
from semmap.labels import INDOOR_LABELS
from semmap.perception.networks.registry import NetworkSpec, build_network, load_weights, save_weights
from semmap.run.adapt import read_run_config, trainable_weights
from semmap.sim.export import simulate_sequence
from semmap.types import CameraIntrinsics

CAMERA = CameraIntrinsics(80, 60, 70.0, 70.0, 39.5, 29.5)


def cli(*args: str):
    """``semmap ARGS`` in this process (the commands' own code; main() turns a SemmapError into one line)."""
    return CliRunner().invoke(app, list(args))


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    return simulate_sequence(tmp_path_factory.mktemp("seq") / "seq", frames=6, size="small", intrinsics=CAMERA,
                             scene_seed=3, trajectory="desk")


@pytest.fixture(scope="module")
def weights(tmp_path_factory) -> Path:
    """A small FCN over the simulator's classes, as a user's own ``semmap train`` run leaves it."""
    torch.manual_seed(0)
    spec = NetworkSpec("fcn", len(INDOOR_LABELS), width=0.125, depth=18, backbone="resnet")
    path = tmp_path_factory.mktemp("weights") / "best.pt"
    return save_weights(path, build_network(spec), spec, INDOOR_LABELS, (40, 30), {"temperature": 1.0})


@pytest.mark.slow  # (three mapping runs and an adaptation: over 5 s)
def test_run_adapt_maps_adapts_and_maps_again_with_the_adapted_weights(sequence, weights, tmp_path):
    out = tmp_path / "loop"
    args = ("run", str(sequence), "--out", str(out), "--segmenter", "fcn", "--weights", str(weights),
            "--resolution", "0.1", "--no-cloud", "--adapt", "--adapt-steps", "2")
    r = cli(*args)
    assert r.exit_code == 0, r.output
    rounds = json.loads((out / "rounds.json").read_text())["rounds"]
    assert [row["round"] for row in rounds] == [0, 1]
    adapted = out / "adapt-1" / "best.pt"
    assert rounds[0]["weights"] == str(weights) and rounds[1]["weights"] == str(adapted)
    assert read_run_config(out / "round-1").semantics.weights == adapted  # round 1 mapped with the adapted network
    assert "pixel_miou_map" in rounds[1] and rounds[1]["adapt_best_step"] in (0, 2)
    assert load_weights(adapted).meta["adapt"]["run"] == str(out / "round-0")
    assert (out / "rounds.md").is_file() and "round 1" in r.output
    mtime = adapted.stat().st_mtime_ns
    again = cli(*args)  # a finished loop is not done again
    assert again.exit_code == 0, again.output
    assert adapted.stat().st_mtime_ns == mtime
    reused = cli("run", str(sequence), "--out", str(tmp_path / "reuse"), "--segmenter", "fcn", "--weights",
                 str(adapted), "--resolution", "0.1", "--no-cloud")
    assert reused.exit_code == 0, reused.output


@pytest.mark.slow  # (a mapping run and an adaptation: over 5 s)
def test_adapt_command_writes_the_weights_and_prints_its_table(sequence, weights, tmp_path):
    run = tmp_path / "run"
    r = cli("run", str(sequence), "--out", str(run), "--segmenter", "fcn", "--weights", str(weights),
            "--resolution", "0.1", "--no-cloud")
    assert r.exit_code == 0, r.output
    r = cli("adapt", str(run), "--out", str(tmp_path / "adapted"), "--steps", "2", "--eval-every", "1",
            "--min-views", "1", "--json")
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    assert [row["step"] for row in report["rows"]] == [0, 1, 2] and report["replay"]["source"] == "none"
    assert report["pseudo_labels"]["frames"] == 6 and "accuracy" in report["pseudo_labels"]
    assert (tmp_path / "adapted" / "best.pt").is_file()
    bad = cli("adapt", str(run), "--out", str(tmp_path / "other"), "--min-confidence", "1.5")
    assert isinstance(bad.exception, SemmapError) and "--min-confidence" in str(bad.exception)


@pytest.mark.parametrize("semantics", [
    {"segmenter": "onnx", "model": "model.onnx"}, {"segmenter": "hf", "model": "some/model"},
    {"segmenter": "precomputed", "weights": "preds"}, {"segmenter": "oracle"}, {"source": "oracle"},
    {"source": "labels"},
])
def test_a_segmenter_adapt_cannot_train_is_refused_in_one_line(semantics, tmp_path):
    config = RunConfig(input=InputConfig(dataset=tmp_path), semantics=SemanticsConfig(**semantics),
                       output=OutputConfig(out=tmp_path / "run"))
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.json").write_text(config.to_json())
    with pytest.raises(ConfigError, match="fine-tune") as err:
        trainable_weights(read_run_config(tmp_path / "run"), tmp_path / "run")
    assert "\n" not in str(err.value)
    r = cli("adapt", str(tmp_path / "run"), "--out", str(tmp_path / "out"))
    assert isinstance(r.exception, SemmapError) and "fine-tune" in str(r.exception)
    assert not (tmp_path / "out").exists()  # refused before any work


def test_a_run_mapped_with_espnetv2_and_structure_adapts_espnetv2(tmp_path):
    """The real default (``espnetv2+structure``) adapts ESPNetv2, from the run's weights or the shipped file."""
    from semmap.perception.registry import shipped_espnetv2

    for weights, expected in ((None, shipped_espnetv2()), (shipped_espnetv2("s1"), shipped_espnetv2("s1"))):
        config = RunConfig(input=InputConfig(dataset=tmp_path), output=OutputConfig(out=tmp_path / "run"),
                           semantics=SemanticsConfig(segmenter="espnetv2", add_structure=True, weights=weights))
        assert trainable_weights(config, tmp_path / "run") == ("espnetv2", expected)
    gone = RunConfig(input=InputConfig(dataset=tmp_path), output=OutputConfig(out=tmp_path / "run"),
                     semantics=SemanticsConfig(segmenter="espnetv2", weights=tmp_path / "gone.pth"))
    with pytest.raises(ConfigError, match="not there any more"):
        trainable_weights(gone, tmp_path / "run")


def test_a_folder_that_is_not_a_finished_run_is_one_line(tmp_path):
    (tmp_path / "folder").mkdir()
    r = cli("adapt", str(tmp_path / "folder"), "--out", str(tmp_path / "out"))
    assert isinstance(r.exception, SemmapError) and "config.json" in str(r.exception)
    assert "\n" not in str(r.exception)
