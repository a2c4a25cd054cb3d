"""ROS bags without ROS: bags written by rosbags' own writers (ROS 1, ROS 2 sqlite3 and mcap) read back as the
frames they were made from, with poses from /tf, a pose topic or Odometry, and `semmap run` on a bag."""

from __future__ import annotations

import json

import numpy as np
import pytest

from helpers import make_room_frames, run_cli
from ros_helpers import DEPTH, RGB, write_bag
from semmap.datasets import open_dataset
from semmap.datasets._ros_tf import TransformTree
from semmap.errors import DatasetError
from semmap.types import make_pose

T0 = 1700000000.0


@pytest.fixture(scope="module")
def frames():
    return [f.with_(timestamp=T0 + f.timestamp, name=f"{T0 + f.timestamp:.6f}") for f in make_room_frames(6)]


def _assert_frames_match(read, frames, *, depth_atol=0.0006, rgb_exact=True):
    assert len(read) == len(frames)
    for got, want in zip(read, frames, strict=True):
        assert got.timestamp == pytest.approx(want.timestamp, abs=1e-6)
        if rgb_exact:
            np.testing.assert_array_equal(got.rgb, want.rgb)
        else:
            assert np.abs(got.rgb.astype(int) - want.rgb).mean() < 4  # lossy JPEG
        np.testing.assert_allclose(got.depth, want.depth, atol=depth_atol)
        assert got.intrinsics == want.intrinsics
        np.testing.assert_allclose(got.T_world_cam, want.T_world_cam, atol=1e-9)


@pytest.mark.parametrize(("kind", "color", "depth", "poses"), [
    ("ros1", "rgb8", "16UC1", "tf"),
    ("sqlite3", "bgr8", "32FC1", "pose"),
    ("mcap", "png", "compressedDepth", "odometry"),
    ("ros1", "rgb8", "32FC1_be", "pose"),
    ("sqlite3", "rgb8", "png16", "tf"),
])
def test_bag_reads_back_as_the_frames_it_was_written_from(frames, tmp_path, kind, color, depth, poses):
    path = tmp_path / ("rec.bag" if kind == "ros1" else "rec")
    write_bag(path, frames, kind=kind, color=color, depth=depth, poses=poses)
    options = {"pose_topic": {"pose": "/camera/pose", "odometry": "/odom"}.get(poses)}
    if poses == "odometry":
        options["camera_frame"] = "camera"
    ds = open_dataset(path, ros=options)
    assert type(ds).__name__ == "RosbagDataset"
    exact_depth = depth.startswith("32FC1")
    _assert_frames_match(list(ds), frames, depth_atol=1e-7 if exact_depth else 0.0006)
    assert ds.skipped == []


def test_jpeg_colour_and_a_ros2_storage_file_path(frames, tmp_path):
    write_bag(tmp_path / "rec", frames, kind="mcap", color="jpeg", depth="16UC1", poses="tf")
    storage = next((tmp_path / "rec").glob("*.mcap"))
    _assert_frames_match(list(open_dataset(storage)), frames, rgb_exact=False)


def test_depth_is_paired_by_nearest_timestamp_within_the_tolerance(frames, tmp_path):
    path = write_bag(tmp_path / "late.bag", frames, depth_offset=0.008, drop_depth=(2,))
    ds = open_dataset(path)
    read = list(ds)
    assert [f.name for f in read] == [f.name for i, f in enumerate(frames) if i != 2]
    np.testing.assert_allclose(read[2].depth, frames[3].depth, atol=0.0006)
    with pytest.raises(DatasetError, match=r"within 0\.005 s"):
        open_dataset(path, ros={"max_time_diff": 0.005})


def test_stride_and_max_frames_apply_to_bags(frames, tmp_path):
    path = write_bag(tmp_path / "b.bag", frames)
    ds = open_dataset(path, stride=2, max_frames=2)
    assert [f.name for f in ds] == [frames[0].name, frames[2].name]


def test_frames_have_no_pose_without_transforms_and_intrinsics_are_assumed_loudly(frames, tmp_path, caplog):
    path = write_bag(tmp_path / "bare.bag", frames, poses="none", camera_info=False)
    ds = open_dataset(path)
    read = list(ds)
    assert all(f.T_world_cam is None for f in read)
    assert ds.intrinsics.width == frames[0].intrinsics.width
    assert "no usable CameraInfo; assuming fx = fy" in caplog.text


def test_unknown_topic_lists_the_bags_topics(frames, tmp_path):
    path = write_bag(tmp_path / "b.bag", frames)
    with pytest.raises(DatasetError, match=rf"--rgb-topic /nope: no such topic.*{RGB} \(Image\)"):
        open_dataset(path, ros={"rgb_topic": "/nope"})
    with pytest.raises(DatasetError, match="is sensor_msgs/msg/CameraInfo, expected Image or CompressedImage"):
        open_dataset(path, ros={"depth_topic": "/camera/color/camera_info"})
    with pytest.raises(DatasetError, match="world-frame nowhere: not in /tf"):
        open_dataset(path, ros={"world_frame": "nowhere"})


def test_unsupported_encoding_and_damaged_bag_are_one_clear_error(frames, tmp_path):
    path = write_bag(tmp_path / "mono.bag", frames, depth="mono16")
    assert len(list(open_dataset(path))) == len(frames)  # mono16 is millimetres like 16UC1
    garbage = tmp_path / "garbage.bag"
    garbage.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 8)
    with pytest.raises(DatasetError, match=r"garbage\.bag: cannot read the bag"):
        open_dataset(garbage)
    truncated = tmp_path / "truncated.bag"
    truncated.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    with pytest.raises(DatasetError, match=r"truncated\.bag"):
        list(open_dataset(truncated))


def test_transform_tree_composes_and_interpolates_a_chain():
    tree = TransformTree()
    tree.add("map", "odom", 0.0, make_pose(np.eye(3), [1, 0, 0]), static=True)
    tree.add("odom", "base", 0.0, make_pose(np.eye(3), [0, 0, 0]))
    tree.add("odom", "base", 0.4, make_pose(np.eye(3), [0, 2, 0]))
    tree.add("odom", "base", 2.0, make_pose(np.eye(3), [0, 2, 0]))
    T, why = tree.lookup("map", "base", 0.1, 0.02)
    np.testing.assert_allclose(T[:3, 3], [1, 0.5, 0], atol=1e-12)
    T, why = tree.lookup("map", "base", 1.0, 0.02)
    assert T is None and "gap of 1.60 s" in why
    assert tree.root_of("base") == "map"
    T, why = tree.lookup("map", "base", 3.0, 0.02)
    assert T is None and "outside the transforms' time range" in why
    T, why = tree.lookup("map", "camera", 0.5, 0.02)
    assert T is None and "no chain" in why


@pytest.mark.slow
def test_semmap_run_maps_a_bag(frames, tmp_path):
    path = write_bag(tmp_path / "rec", frames, kind="sqlite3", depth="compressedDepth")
    out = tmp_path / "out"
    r = run_cli("run", str(path), "--out", str(out), "--resolution", "0.1", "--depth-topic",
                DEPTH + "/compressedDepth", "--semantics", "none")  # (a real recording's default segments)
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["frames_used"] == len(frames) and report["occupied_voxels"] > 100


@pytest.mark.parametrize("kind", ["ros1", "sqlite3"])
def test_a_bags_imu_gives_each_frame_its_up_direction_in_the_camera_frame(frames, tmp_path, kind):
    """The accelerometer sits on the robot body; /tf_static carries its reading into the camera's frame."""
    name = "rec.bag" if kind == "ros1" else "rec"
    path = write_bag(tmp_path / name, frames, kind=kind, poses="tf", imu=True)
    got = list(open_dataset(path))
    assert len(got) == len(frames)
    for f in got:
        assert f.up_cam is not None
        assert np.allclose(f.up_cam, f.T_world_cam[:3, :3].T @ [0.0, 0.0, 1.0], atol=1e-6)
    # without the body -> camera transform the readings cannot be placed: frames get none, said once
    (tmp_path / "alone").mkdir()
    alone = write_bag(tmp_path / "alone" / name, frames, kind=kind, poses="none", imu=True)
    assert all(f.up_cam is None for f in open_dataset(alone))
