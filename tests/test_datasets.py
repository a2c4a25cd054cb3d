"""Dataset readers: TUM RGB-D, 7-Scenes, label folders, format detection and the TUM writer."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import SMALL_CAMERA, make_frames, rotation_z, write_7scenes_sequence, write_png
from semmap.datasets import (
    Dataset,
    LabelFolder,
    SevenScenesDataset,
    TumDataset,
    detect_format,
    open_dataset,
    read_label_image,
    write_tum_sequence,
)
from semmap.datasets.tum import associate
from semmap.errors import ConfigError, DatasetError
from semmap.types import CameraIntrinsics, LabelSet, make_pose, pose_to_tum

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REDKITCHEN = SHARED / "data" / "7scenes-redkitchen"
T0 = 1305031102.175304
DT = 1 / 30


@pytest.fixture
def tum_seq(tmp_path: Path) -> Path:
    """Five frames written with the TUM writer, labels and instances included."""
    root = tmp_path / "seq"
    write_tum_sequence(root, make_frames(5), label_set=LabelSet.generic(300))
    return root


@pytest.fixture
def scenes_seq(tmp_path: Path) -> Path:
    """Four 7-Scenes frames (numbers 0..3)."""
    return write_7scenes_sequence(tmp_path / "chess", make_frames(4, with_labels=False))


def _stamp(i: int) -> str:
    return f"{T0 + i * DT:.6f}"


def _write_list(path: Path, rows: list[tuple[float | str, str]]) -> None:
    path.write_text("# rewritten by the test\n" + "".join(f"{t} {p}\n" for t, p in rows))


def _write_groundtruth(path: Path, rows: list[tuple[float, np.ndarray]]) -> None:
    path.write_text("".join(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in pose_to_tum(T)) + "\n"
                            for t, T in rows))


# --------------------------------------------------------------------------------------------------
# TUM writer and reader
# --------------------------------------------------------------------------------------------------
def test_tum_round_trip_returns_the_written_frames(tum_seq: Path) -> None:
    written = make_frames(5)
    ds = TumDataset(tum_seq)
    read = list(ds)
    assert isinstance(ds, Dataset)
    assert len(ds) == len(read) == 5 and ds.skipped == []
    assert ds.intrinsics == SMALL_CAMERA
    assert ds.label_set.names == LabelSet.generic(300).names
    assert np.array_equal(ds.label_set.colors, LabelSet.generic(300).colors)
    for a, b in zip(written, read, strict=True):
        assert b.index == a.index and b.name == _stamp(a.index)
        assert b.timestamp == pytest.approx(a.timestamp, abs=1e-6)
        assert b.rgb.dtype == np.uint8 and np.array_equal(b.rgb, a.rgb)
        assert b.depth.dtype == np.float32 and np.abs(b.depth - a.depth).max() <= 1 / 5000
        assert np.array_equal(b.depth == 0, a.depth == 0)
        assert b.T_world_cam.dtype == np.float64 and np.allclose(b.T_world_cam, a.T_world_cam, atol=1e-6)
        assert b.labels.dtype == np.uint16 and np.array_equal(b.labels, a.labels)
        assert b.instances.dtype == np.int32 and np.array_equal(b.instances, a.instances)


def test_tum_writer_is_byte_identical_for_the_same_frames(tmp_path: Path) -> None:
    write_tum_sequence(tmp_path / "a", make_frames(3))
    write_tum_sequence(tmp_path / "b", iter(make_frames(3)))
    files_a = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    assert files_a == files_b and len(files_a) == 3 * 4 + 4
    for rel in files_a:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


def test_tum_writer_refuses_duplicate_timestamps(tmp_path: Path) -> None:
    frame = make_frames(1)[0]
    with pytest.raises(DatasetError, match="share the timestamp"):
        write_tum_sequence(tmp_path, [frame, frame])


def test_association_pairs_closest_stamps_within_max_difference(tum_seq: Path) -> None:
    # depth jittered by +5 ms, +7 ms, -15 ms, +29 ms (too far), -1 ms
    jitter = [0.005, 0.007, -0.015, 0.029, -0.001]
    _write_list(tum_seq / "depth.txt", [(f"{T0 + i * DT + j:.6f}", f"depth/{_stamp(i)}.png")
                                        for i, j in enumerate(jitter)])
    names = [f.name for f in TumDataset(tum_seq)]
    assert names == [_stamp(i) for i in (0, 1, 2, 4)]
    assert len(TumDataset(tum_seq, max_time_diff=0.01)) == 3
    assert len(TumDataset(tum_seq, max_time_diff=0.03)) == 5


def test_association_is_one_to_one_and_greedy_by_smallest_difference() -> None:
    # depth 1.008 is closer to rgb 1.01 (2 ms) than to rgb 1.0 (8 ms): rgb 1.0 then takes nothing
    assert associate([1.0, 1.01], [1.008], 0.02) == [(1, 0)]
    assert associate([1.0, 1.01, 2.0], [1.001, 1.012, 2.5], 0.02) == [(0, 0), (1, 1)]
    assert associate([], [1.0], 0.02) == []


def test_pose_is_interpolated_between_bracketing_groundtruth_rows(tum_seq: Path) -> None:
    A = make_pose(rotation_z(0.0), [0.0, 0.0, 0.0])
    B = make_pose(rotation_z(0.4), [2.0, -4.0, 1.0])
    t_frame = T0 + 2 * DT
    # rows deliberately out of time order
    _write_groundtruth(tum_seq / "groundtruth.txt", [(t_frame + 1.0, B), (t_frame - 1.0, A)])
    pose = next(f for f in TumDataset(tum_seq) if f.index == 2).T_world_cam
    assert np.allclose(pose[:3, 3], [1.0, -2.0, 0.5], atol=1e-5)
    assert np.allclose(pose[:3, :3], rotation_z(0.2), atol=1e-5)


def test_frame_outside_the_groundtruth_range_has_no_pose(tum_seq: Path) -> None:
    A = make_pose(rotation_z(0.1), [1.0, 2.0, 3.0])
    B = make_pose(rotation_z(0.3), [1.5, 2.0, 3.0])
    # covers frames 1..2 exactly; frame 3 lies 10 ms past the end (clamped), frames 0 and 4 further out
    _write_groundtruth(tum_seq / "groundtruth.txt", [(T0 + DT, A), (T0 + 3 * DT - 0.01, B)])
    poses = {f.index: f.T_world_cam for f in TumDataset(tum_seq)}
    assert poses[0] is None and poses[4] is None
    assert np.allclose(poses[1], A, atol=1e-6)
    assert np.allclose(poses[3], B, atol=1e-6)


def test_sequence_without_groundtruth_has_no_poses(tum_seq: Path) -> None:
    (tum_seq / "groundtruth.txt").unlink()
    assert all(f.T_world_cam is None for f in TumDataset(tum_seq))


def test_nan_in_groundtruth_leaves_those_frames_without_pose_or_stops_when_strict(
        tum_seq: Path, caplog: pytest.LogCaptureFixture) -> None:
    lines = (tum_seq / "groundtruth.txt").read_text().splitlines()
    lines[3] = f"{_stamp(1)} 0 0 nan 0 0 0 1"
    (tum_seq / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="semmap"):
        frames = list(TumDataset(tum_seq))
    assert frames[1].T_world_cam is None and frames[0].T_world_cam is not None  # the pipeline skips it: no pose
    assert "groundtruth.txt: 1 poses have non-finite entries or positions beyond ±1e+08 m (lines 4)" in caplog.text
    with pytest.raises(DatasetError, match=r"groundtruth.txt:4: pose has non-finite"):
        TumDataset(tum_seq, strict=True)


def test_missing_depth_file_is_skipped_with_a_warning(tum_seq: Path,
                                                       caplog: pytest.LogCaptureFixture) -> None:
    missing = tum_seq / "depth" / f"{_stamp(2)}.png"
    missing.unlink()
    ds = TumDataset(tum_seq)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        frames = list(ds)
    assert len(ds) == 5
    assert [f.index for f in frames] == [0, 1, 3, 4]
    assert len(ds.skipped) == 1
    assert ds.skipped[0].name == _stamp(2) and ds.skipped[0].path == str(missing)
    assert "missing" in ds.skipped[0].reason
    assert str(missing) in caplog.text


def test_truncated_png_is_skipped_with_a_warning_naming_it(tum_seq: Path,
                                                            caplog: pytest.LogCaptureFixture) -> None:
    corrupt = tum_seq / "rgb" / f"{_stamp(1)}.png"
    data = corrupt.read_bytes()
    corrupt.write_bytes(data[: len(data) // 2])
    ds = TumDataset(tum_seq)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        frames = list(ds)
    assert [f.index for f in frames] == [0, 2, 3, 4]
    assert [s.path for s in ds.skipped] == [str(corrupt)]
    assert str(corrupt) in caplog.text and "corrupt" in caplog.text
    list(ds)  # a second pass starts a fresh record
    assert len(ds.skipped) == 1


def test_image_size_not_matching_the_intrinsics_skips_the_frame_or_stops_when_strict(tum_seq: Path) -> None:
    wrong = CameraIntrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)
    (tum_seq / "camera.json").write_text(json.dumps(wrong.to_dict()))
    ds = TumDataset(tum_seq)
    assert list(ds) == [] and "colour image is 32x24, expected 64x48" in ds.skipped[0].reason
    with pytest.raises(DatasetError, match=r"rgb/.*\.png: colour image is 32x24, expected 64x48.*--strict"):
        next(iter(TumDataset(tum_seq, strict=True)))


def test_intrinsics_come_from_the_argument_camera_json_sequence_name_or_default(tmp_path: Path) -> None:
    for folder in ("rgbd_dataset_freiburg1_xyz", "plain"):
        write_tum_sequence(tmp_path / folder, make_frames(2))
        (tmp_path / folder / "camera.json").unlink()
    fr1 = TumDataset(tmp_path / "rgbd_dataset_freiburg1_xyz").intrinsics
    assert (fr1.fx, fr1.fy, fr1.cx, fr1.cy, fr1.width, fr1.height) == (517.3, 516.5, 318.6, 255.3, 32, 24)
    default = TumDataset(tmp_path / "plain").intrinsics
    assert (default.fx, default.cx, default.width) == (525.0, 319.5, 32)
    given = CameraIntrinsics(32, 24, 40.0, 41.0, 16.0, 12.0)
    assert TumDataset(tmp_path / "plain", intrinsics=given).intrinsics == given


def test_labels_dir_overrides_the_labels_folder(tum_seq: Path, tmp_path: Path) -> None:
    other = tmp_path / "predicted"
    ids = np.full((24, 32), 7, np.uint16)
    for i in range(5):
        write_png(other / f"{_stamp(i)}.png", ids)
    frames = list(TumDataset(tum_seq, labels_dir=other))
    assert all(np.array_equal(f.labels, ids) for f in frames)
    assert all(f.instances is not None for f in frames)


# --------------------------------------------------------------------------------------------------
# 7-Scenes
# --------------------------------------------------------------------------------------------------
def test_sevenscenes_reads_frames_poses_and_intrinsics(scenes_seq: Path) -> None:
    written = make_frames(4, with_labels=False)
    ds = SevenScenesDataset(scenes_seq)
    frames = list(ds)
    assert ds.name == "chess" and ds.intrinsics == SMALL_CAMERA and ds.label_set is None
    assert [f.name for f in frames] == [f"frame-{i:06d}" for i in range(4)]
    for a, b in zip(written, frames, strict=True):
        assert b.index == a.index and b.timestamp == pytest.approx(a.index / 30)
        assert np.array_equal(b.rgb, a.rgb)
        assert np.abs(b.depth - a.depth).max() <= 0.5e-3 + 1e-6
        assert np.allclose(b.T_world_cam, a.T_world_cam, atol=1e-12)
        assert b.labels is None and b.instances is None


def test_sevenscenes_without_intrinsics_file_uses_the_default(scenes_seq: Path) -> None:
    (scenes_seq / "camera-intrinsics.txt").unlink()
    cam = SevenScenesDataset(scenes_seq).intrinsics
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (585.0, 585.0, 320.0, 240.0, 32, 24)


def test_sevenscenes_depth_65535_is_invalid(scenes_seq: Path) -> None:
    depth = np.full((24, 32), 1500, np.uint16)
    depth[0, :5] = 65535
    write_png(scenes_seq / "frame-000000.depth.png", depth)
    first = next(iter(SevenScenesDataset(scenes_seq)))
    assert (first.depth[0, :5] == 0).all() and first.depth[1, 0] == pytest.approx(1.5)


def test_nan_pose_in_sevenscenes_skips_the_frame_or_stops_when_strict(scenes_seq: Path) -> None:
    bad = np.eye(4)
    bad[1, 3] = np.nan
    np.savetxt(scenes_seq / "frame-000002.pose.txt", bad)
    ds = SevenScenesDataset(scenes_seq)
    assert [f.index for f in ds] == [0, 1, 3] and ds.skipped[0].reason.startswith("pose has non-finite")
    with pytest.raises(DatasetError, match=r"frame-000002\.pose\.txt: pose has non-finite"):
        list(SevenScenesDataset(scenes_seq, strict=True))


def test_missing_pose_file_in_sevenscenes_skips_the_frame(scenes_seq: Path,
                                                         caplog: pytest.LogCaptureFixture) -> None:
    (scenes_seq / "frame-000001.pose.txt").unlink()
    ds = SevenScenesDataset(scenes_seq)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        assert [f.index for f in ds] == [0, 2, 3]
    assert [s.name for s in ds.skipped] == ["frame-000001"]
    assert "frame-000001.pose.txt" in caplog.text


def test_depth_of_another_size_skips_the_frame_or_stops_when_strict(scenes_seq: Path) -> None:
    write_png(scenes_seq / "frame-000003.depth.png", np.ones((12, 16), np.uint16))
    assert [f.index for f in SevenScenesDataset(scenes_seq)] == [0, 1, 2]
    with pytest.raises(DatasetError, match=r"frame-000003\.depth\.png: depth image is 16x12, expected 32x24"):
        list(SevenScenesDataset(scenes_seq, strict=True))


def test_sevenscenes_reads_jpeg_colour(tmp_path: Path) -> None:
    root = write_7scenes_sequence(tmp_path / "jpg", make_frames(2, with_labels=False), color_ext=".jpg")
    frames = list(SevenScenesDataset(root))
    assert [f.name for f in frames] == ["frame-000000", "frame-000001"]
    assert frames[0].rgb.shape == (24, 32, 3)


# --------------------------------------------------------------------------------------------------
# Options, detection, label folders
# --------------------------------------------------------------------------------------------------
def test_stride_and_max_frames_select_from_the_original_sequence(tmp_path: Path) -> None:
    root = write_7scenes_sequence(tmp_path / "s", make_frames(10, with_labels=False))
    ds = SevenScenesDataset(root, stride=3)
    assert len(ds) == 4 and [f.index for f in ds] == [0, 3, 6, 9]
    ds = open_dataset(root, stride=3, max_frames=2)
    assert len(ds) == 2 and [f.index for f in ds] == [0, 3]
    assert len(open_dataset(root, max_frames=0)) == 0
    with pytest.raises(ConfigError, match="stride"):
        SevenScenesDataset(root, stride=0)


def test_detect_format_recognises_both_layouts(tum_seq: Path, scenes_seq: Path) -> None:
    assert detect_format(tum_seq) == "tum"
    assert detect_format(scenes_seq) == "7scenes"
    assert isinstance(open_dataset(tum_seq), TumDataset)
    assert isinstance(open_dataset(scenes_seq), SevenScenesDataset)
    assert isinstance(open_dataset(tum_seq, "tum", depth_scale=5000.0), TumDataset)


def test_detect_format_on_an_empty_folder_lists_what_it_looked_for(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"rgb\.txt.*frame-\*\.color"):
        detect_format(tmp_path)
    with pytest.raises(DatasetError, match="does not exist"):
        open_dataset(tmp_path / "nowhere")
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(DatasetError, match="expected a dataset folder"):
        open_dataset(tmp_path / "file.txt")
    with pytest.raises(DatasetError, match="unknown dataset format 'kitti'"):
        open_dataset(tmp_path, "kitti")


def test_label_folder_matches_frames_by_stem(tmp_path: Path) -> None:
    ids = np.zeros((24, 32), np.uint16)
    for name in ("frame-000001.png", "frame-000002.label.png", "frame-000003.labels.png", f"{T0:.6f}.png"):
        write_png(tmp_path / name, ids)
    folder = LabelFolder(tmp_path)
    assert folder.lookup("frame-000001") == tmp_path / "frame-000001.png"
    assert folder.lookup("frame-000002") == tmp_path / "frame-000002.label.png"
    assert folder.lookup("frame-000003") == tmp_path / "frame-000003.labels.png"
    assert folder.lookup(f"{T0:.6f}") == tmp_path / f"{T0:.6f}.png"
    assert folder.lookup("frame-000004") is None
    assert folder.label_set is None
    with pytest.raises(DatasetError, match="does not exist"):
        LabelFolder(tmp_path / "nowhere")


def test_frames_without_a_label_png_keep_labels_none_and_warn(scenes_seq: Path, tmp_path: Path,
                                                              caplog: pytest.LogCaptureFixture) -> None:
    folder = tmp_path / "labels"
    for i in (1, 2, 3):
        write_png(folder / f"frame-{i:06d}.label.png", np.full((24, 32), i, np.uint8))
    LabelSet.generic(4).save(folder / "labelset.json")
    ds = open_dataset(scenes_seq, labels=folder)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        frames = list(ds)
    assert ds.label_set is not None and ds.label_set.names == LabelSet.generic(4).names
    assert len(frames) == 4 and ds.skipped == []
    assert frames[0].labels is None
    assert [int(f.labels[0, 0]) for f in frames[1:]] == [1, 2, 3] and frames[1].labels.dtype == np.uint16
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and str(folder / "frame-000000.png") in warnings[0]


def test_colour_label_image_is_rejected_naming_the_file(tmp_path: Path) -> None:
    path = write_png(tmp_path / "frame-000000.png", np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(DatasetError, match=r"frame-000000\.png: label image must be single-channel"):
        read_label_image(path)
    assert read_label_image(write_png(tmp_path / "ok.png", np.full((4, 4), 9, np.uint8))).dtype == np.uint16


# --------------------------------------------------------------------------------------------------
# Real data (skipped when ../shared is absent)
# --------------------------------------------------------------------------------------------------
@pytest.fixture
def redkitchen() -> Path:
    if not REDKITCHEN.is_dir():
        pytest.skip(f"real 7-Scenes data not found at {REDKITCHEN}")
    return REDKITCHEN


def test_real_sevenscenes_first_frames_load(redkitchen: Path) -> None:
    assert detect_format(redkitchen) == "7scenes"
    assert len(open_dataset(redkitchen)) == 600
    ds = open_dataset(redkitchen, max_frames=3)
    assert ds.intrinsics == CameraIntrinsics(640, 480, 585.0, 585.0, 320.0, 240.0)
    frames = list(ds)
    assert [f.name for f in frames] == ["frame-000000", "frame-000001", "frame-000002"] and ds.skipped == []
    for f in frames:
        assert f.rgb.shape == (480, 640, 3) and f.depth.shape == (480, 640)
        assert 250_000 < int((f.depth > 0).sum()) < 300_000
        assert 0.2 < float(np.median(f.depth[f.depth > 0])) < 8.0
        assert np.isfinite(f.T_world_cam).all()


def test_real_sevenscenes_colour_is_registered_onto_depth(redkitchen: Path) -> None:
    """The 7-Scenes colour camera (f = 526 px, 3 cm to the side) is resampled onto the depth camera: depth outlines
    then fall on colour edges; ``raw_color`` keeps the stored image."""
    from semmap.eval.registration import edge_misalignment

    registered = open_dataset(redkitchen, stride=150)
    assert registered.registers_color
    raw = open_dataset(redkitchen, stride=150, raw_color=True)
    assert not raw.registers_color
    before, after = [], []
    for a, b in zip(raw, registered, strict=True):
        assert a.rgb.shape == b.rgb.shape and not np.array_equal(a.rgb, b.rgb)
        assert a.raw_color is None and np.array_equal(b.raw_color.image, a.rgb)  # the camera's own view, kept
        np.testing.assert_array_equal(a.depth, b.depth)
        before.append(edge_misalignment(a.rgb, a.depth))
        after.append(edge_misalignment(b.rgb, b.depth))
    assert np.mean(after) < 0.75 * np.mean(before)


def test_sevenscenes_layout_from_another_camera_keeps_its_colour(scenes_seq: Path) -> None:
    assert not SevenScenesDataset(scenes_seq).registers_color


def test_copied_real_frame_with_missing_depth_is_skipped(redkitchen: Path, tmp_path: Path) -> None:
    for suffix in (".color.jpg", ".depth.png", ".pose.txt"):
        for i in (0, 1):
            shutil.copy(redkitchen / f"frame-{i:06d}{suffix}", tmp_path)
    (tmp_path / "frame-000001.depth.png").unlink()
    ds = SevenScenesDataset(tmp_path)
    assert [f.name for f in ds] == ["frame-000000"]
    assert ds.skipped[0].path.endswith("frame-000001.depth.png")
