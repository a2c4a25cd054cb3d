"""The tracking, object and fusion benchmarks render their simulated frames with a ``--realism`` preset
(issue 34: ``kinect`` by default, ``clean`` still available)."""

from __future__ import annotations

import argparse
import sys

import numpy as np
import pytest

from script_modules import load_script
from semmap.types import CameraIntrinsics


def bench(name: str):
    """The benchmark script ``name`` imported as a module (its ``main`` is not run)."""
    return load_script(f"benchmarks/{name}.py")


@pytest.mark.parametrize("name", ["bench_tracking", "bench_objects", "bench_fusion"])
def test_default_realism_is_kinect(name):
    assert bench(name).DEFAULT_REALISM == "kinect"


@pytest.mark.slow
def test_tracking_sequences_follow_the_preset():
    tracking = bench("bench_tracking")
    clean = tracking.load_sequence("sim-desk", 2, "clean")
    kinect = tracking.load_sequence("sim-desk", 2, "kinect")
    assert len(clean) == len(kinect) == 2
    # the structured-light sensor drops pixels the clean simulator measures
    assert (kinect[1].depth == 0).mean() > (clean[1].depth == 0).mean()


@pytest.mark.slow
def test_fusion_render_follows_the_preset():
    fusion = bench("bench_fusion")
    tiny = CameraIntrinsics(80, 60, 65.6, 65.6, 39.5, 29.5)
    clean = fusion.render("office", 0, "small", 2, 3, tiny, "clean")
    kinect = fusion.render("office", 0, "small", 2, 3, tiny, "kinect")
    assert not np.array_equal(clean.frames[1].depth, kinect.frames[1].depth)


def test_object_scenes_subset_and_frames():
    objects = bench("bench_objects")
    ap = argparse.ArgumentParser()
    args = argparse.Namespace(quick=False, scenes="living-walk", frames=40)
    assert objects._chosen_scenes(ap, args) == {"living-walk": (2, "living_room", "walk", 40)}
    with pytest.raises(SystemExit):
        objects._chosen_scenes(ap, argparse.Namespace(quick=False, scenes="nowhere", frames=None))


def test_object_pose_runs_subset_alone_skips_the_object_scenes():
    objects = bench("bench_objects")
    ap = argparse.ArgumentParser()
    args = argparse.Namespace(quick=False, scenes=None, frames=None, pose_runs="sim-loop-odometry")
    assert objects._chosen_pose_runs(ap, args) == {"sim-loop-odometry": (1, "office", "loop", 450, "odometry")}
    assert objects._chosen_scenes(ap, args) == {}
    with pytest.raises(SystemExit):
        objects._chosen_pose_runs(ap, argparse.Namespace(quick=False, pose_runs="nowhere"))


def test_fusion_resolution_outside_its_range_is_refused(monkeypatch, capsys):
    fusion = bench("bench_fusion")
    monkeypatch.setattr(sys, "argv", ["bench_fusion.py", "--resolution", "0.9"])
    with pytest.raises(SystemExit):
        fusion.main()
    assert "--resolution must be from 0.005 to 0.5 m, got 0.9" in capsys.readouterr().err
    assert fusion.RESOLUTION == 0.05  # (the refused value never became the run's voxel size)


def test_fusion_settings_are_chosen_on_validation_scenes_apart_from_the_held_out_ones():
    fusion = bench("bench_fusion")
    seeds = {seed for _, seed, _ in fusion.VALIDATION_SCENES}
    assert seeds <= set(range(300, 308))  # the networks' validation seeds (scripts/make_training_data.py)
    assert not seeds & {seed for _, seed, _ in fusion.QUICK_SCENES + fusion.SCENES}
