"""Online runs: frames mapped as the tracker poses them, segmentation beside tracking, bounded queues."""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import make_room_frames, room_label_set, run_cli
from semmap.config import (
    InputConfig,
    LoopMode,
    MappingConfig,
    OnlineConfig,
    OutputConfig,
    PosesConfig,
    RunConfig,
    SemanticsConfig,
)
from semmap.io.trajectory import read_trajectory
from semmap.io.tum_writer import write_tum_sequence
from semmap.perception.network import NetworkInput, NetworkSegmenter
from semmap.perception.schedule import (
    Scheduler,
    SegmentationSchedule,
    SegmentationWorker,
    with_semantics,
    with_semantics_beside,
)
from semmap.pipeline import Pipeline
from semmap.types import TopKProbs


class _Net(torch.nn.Module):
    """A fixed 1x1 convolution at half resolution: deterministic logits over the room's classes."""

    def __init__(self, classes: int):
        super().__init__()
        torch.manual_seed(0)
        self.conv = torch.nn.Conv2d(3, classes, 1)

    def forward(self, x):
        return self.conv(torch.nn.functional.avg_pool2d(x, 2))


def _segmenter() -> NetworkSegmenter:
    labels = room_label_set()
    return NetworkSegmenter(_Net(len(labels)), labels, name="tiny", net_input=NetworkInput(size=(48, 32)), k=3)


def _slow_room_frames(n: int) -> list:
    """Room frames 0.05 rad apart (``make_room_frames`` steps 0.4 rad, too far for odometry at 80x60 pixels)."""
    frames = []
    for i in range(n):
        f = make_room_frames(1, start=0.05 * i)[0]
        frames.append(dataclasses.replace(f, index=i, timestamp=i / 30, name=f"{i / 30:.6f}"))
    return frames


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("room-online")
    write_tum_sequence(root, _slow_room_frames(10), label_set=room_label_set())
    return root


def _run(room: Path, out: Path, mode: LoopMode, poses: str = "gt"):
    config = RunConfig(input=InputConfig(dataset=room), mapping=MappingConfig(resolution=0.1),
                       semantics=SemanticsConfig(segment_every=3), poses=PosesConfig(source=poses), mode=mode,
                       output=OutputConfig(out=out, preview=False, plots=False))
    return Pipeline(config, segmenter=_segmenter()).run()


def _same_maps(a, b) -> None:
    ca, cb = a.octomap.cells(), b.octomap.cells()
    assert ca.packed.size > 0
    assert np.array_equal(ca.packed, cb.packed) and np.array_equal(ca.logodds, cb.logodds)
    va, vb = a.octomap.voxels(), b.octomap.voxels()
    assert np.array_equal(va.colors, vb.colors) and np.array_equal(va.labels, vb.labels)
    assert np.array_equal(va.probs, vb.probs)


@pytest.mark.slow
def test_online_map_equals_the_offline_map_of_the_same_poses(room, tmp_path):
    offline = _run(room, tmp_path / "off", LoopMode.OFFLINE)
    online = _run(room, tmp_path / "on", LoopMode.ONLINE)
    _same_maps(online, offline)
    assert online.report["frames_segmented"] == offline.report["frames_segmented"] == 4
    o = online.report["online"]
    assert o["fps"] > 0 and 0 < o["latency_ms"]["median"] <= o["latency_ms"]["max"]
    assert o["drift_left_in"]["max_mm"] == 0.0  # ground-truth poses never move


@pytest.mark.slow
def test_online_tracking_maps_with_live_poses_and_reports_the_drift_left_in(room, tmp_path):
    online = _run(room, tmp_path / "on", LoopMode.ONLINE, poses="odometry")
    used = read_trajectory(tmp_path / "on" / "trajectory.txt")
    final = read_trajectory(tmp_path / "on" / "trajectory_final.txt")
    assert len(used) == len(final) == online.report["frames_used"] == 10
    report = json.loads((tmp_path / "on" / "report.json").read_text())
    assert report["online"]["drift_left_in"]["frames"] == 10 and "track" in report["ms_per_frame"]
    # the offline special case, given the poses the online run mapped with, builds the same map
    offline = _run(room, tmp_path / "off", LoopMode.OFFLINE, poses=str(tmp_path / "on" / "trajectory.txt"))
    _same_maps(online, offline)


class _SlowSegmenter:
    """Records how many frames it holds at once; each takes ``seconds``."""

    name = "slow"

    def __init__(self, seconds: float):
        self.seconds, self.inside, self.most = seconds, 0, 0
        self.lock = threading.Lock()
        self.label_set = room_label_set()

    def segment(self, frame):
        with self.lock:
            self.inside += 1
            self.most = max(self.most, self.inside)
        time.sleep(self.seconds)
        with self.lock:
            self.inside -= 1
        h, w = frame.depth.shape
        return TopKProbs(np.full((h, w, 3), frame.index % 7, np.uint16), np.full((h, w, 3), 0.3, np.float32))


def test_segmentation_beside_keeps_frame_order_and_bounds_what_waits():
    frames = make_room_frames(12)
    posed = [(f, f.T_world_cam) for f in frames]
    seg = _SlowSegmenter(0.02)
    waiting = []

    def source():
        for item in posed:
            waiting.append(item[0].index)
            yield item

    with SegmentationWorker(seg, max_queued=2) as worker:
        out = []
        for frame, _T, sem in with_semantics_beside(source(), worker, Scheduler(SegmentationSchedule(every=2)),
                                                    max_pending=3):
            out.append((frame.index, None if sem is None else int(sem.labels[0, 0, 0])))
            assert len(waiting) - len(out) <= 3  # read but not handed on yet
    assert [i for i, _ in out] == list(range(12))
    assert out == [(i, i % 7 if i % 2 == 0 else None) for i in range(12)]
    assert seg.most == 1  # one segmentation thread
    offline = [(f.index, None if s is None else int(s.labels[0, 0, 0]))
               for f, _T, s in with_semantics(posed, _SlowSegmenter(0.0), Scheduler(SegmentationSchedule(every=2)))]
    assert offline == out


def test_submit_blocks_while_the_queue_is_full():
    seg = _SlowSegmenter(0.2)
    frames = make_room_frames(3)
    with SegmentationWorker(seg, max_queued=1) as worker:
        worker.submit(frames[0])
        t0 = time.perf_counter()
        second = worker.submit(frames[1])  # waits for the first to finish
        assert time.perf_counter() - t0 > 0.1
        assert int(second.result()[0].labels[0, 0, 0]) == 1


@pytest.mark.slow
def test_online_flag_on_the_command_line(room, tmp_path):
    out = tmp_path / "cli"
    r = run_cli("run", str(room), "--out", str(out), "--resolution", "0.1", "--online", "--poses", "odometry")
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["online"]["fps"] > 0 and (out / "trajectory_final.txt").is_file()
    assert json.loads((out / "config.json").read_text())["mode"] == "online"


def test_dense_slam_live_pose_is_the_last_frame_through_the_optimised_keyframes():
    from semmap.poses.base import LiveTracker
    from semmap.poses.slam import DenseSlam

    slam = DenseSlam()
    assert isinstance(slam, LiveTracker) and slam.live_pose() is None
    for frame in _slow_room_frames(8):
        slam.track(frame)
    final = slam.trajectory()  # optimises the pose graph; the last frame has no next keyframe to blend towards
    np.testing.assert_allclose(slam.live_pose(), final.poses[-1], atol=1e-9)
    assert slam.loop_closures == 0


def test_frames_read_ahead_come_in_order_bounded_and_stop_with_the_loop():
    from semmap.datasets.prefetch import Prefetcher

    read = []

    def frames():
        for i in range(50):
            read.append(i)
            yield i

    with Prefetcher(frames(), depth=2) as ahead:
        got = []
        for item, stamp in ahead:
            assert stamp <= time.perf_counter()
            got.append(item)
            time.sleep(0.002)
            assert len(read) - len(got) <= 3  # two waiting, one in the reader's hands
            if item == 9:
                break
    assert got == list(range(10)) and len(read) <= 13


def test_a_reader_error_reaches_the_loop():
    from semmap.datasets.prefetch import Prefetcher

    def frames():
        yield 1
        raise OSError("disk gone")

    with Prefetcher(frames()) as ahead, pytest.raises(OSError, match="disk gone"):
        list(ahead)


def test_frames_replayed_at_a_rate_arrive_at_their_due_times_and_not_before():
    from semmap.datasets.prefetch import Prefetcher

    read_at = []

    def frames():
        for i in range(6):
            read_at.append(time.perf_counter())
            yield i

    with Prefetcher(frames(), depth=4, rate=50.0) as paced:
        got = [(item, stamp, time.perf_counter()) for item, stamp in paced]
    assert [g[0] for g in got] == list(range(6))
    stamps = np.array([g[1] for g in got])
    np.testing.assert_allclose(np.diff(stamps), 1 / 50, atol=1e-9)  # one camera period apart, however fast
    assert all(read >= stamp - 1e-6 for read, stamp in zip(read_at, stamps, strict=True))  # never read early
    assert all(taken >= stamp for _, stamp, taken in got)
    with pytest.raises(ValueError, match="positive"):
        Prefetcher(iter(()), rate=0.0)


def test_an_online_run_at_a_camera_rate_measures_latency_from_each_due_time(room, tmp_path):
    config = RunConfig(input=InputConfig(dataset=room), mapping=MappingConfig(resolution=0.1),
                       poses=PosesConfig(source="gt"), mode=LoopMode.ONLINE, online=OnlineConfig(rate=20.0),
                       output=OutputConfig(out=tmp_path / "paced", preview=False, plots=False))
    t0 = time.perf_counter()
    result = Pipeline(config).run()
    assert time.perf_counter() - t0 >= 9 / 20  # ten frames at 20 per second take at least 0.45 s
    latency = result.report["online"]["latency_ms"]
    assert 0 < latency["median"] <= latency["max"] < 1000
    assert result.report["online"]["fps"] <= 21


@pytest.mark.slow
def test_a_rate_needs_an_online_run(room, tmp_path):
    with pytest.raises(ValueError, match="--online"):
        RunConfig(input=InputConfig(dataset=room), online=OnlineConfig(rate=10.0), output=OutputConfig(out=tmp_path))
    r = run_cli("run", str(room), "--out", str(tmp_path / "x"), "--rate", "10")
    assert r.returncode != 0 and "needs an online run" in r.stderr and "Traceback" not in r.stderr
