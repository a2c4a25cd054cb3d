"""rerun logging: a run's .rrd read back with rerun's own reader holds every frame's images and pose, the
trajectory and the map in class colours; `semmap view` writes a finished map the same way."""

from __future__ import annotations

import json

import numpy as np
import pytest

from helpers import make_room_frames, room_label_set, run_cli
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
from semmap.io.tum_writer import write_tum_sequence
from semmap.pipeline import Pipeline
from semmap.viz.rerun_log import NoVisualizer, class_colors, get_visualizer

FRAMES = 7


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("room-rerun")
    write_tum_sequence(root, make_room_frames(FRAMES), label_set=room_label_set())
    return root


def _read_rrd(path):
    """{entity path: list of record batches} through rerun's own chunk reader."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream():
        out.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return out


def _column(batches, name: str) -> list:
    """Values of one component column over all rows (rows in logging order), as Python lists."""
    rows = []
    for batch in batches:
        if name in batch.schema.names:
            order = np.argsort(batch.column("frame").to_numpy()) if "frame" in batch.schema.names else None
            values = batch.column(name).to_pylist()
            rows += [values[i] for i in order] if order is not None else values
    return rows


@pytest.fixture(scope="module")
def logged_run(room, tmp_path_factory):
    out = tmp_path_factory.mktemp("rerun-run")
    rrd = out / "run.rrd"
    config = RunConfig(input=InputConfig(dataset=room), mapping=MappingConfig(resolution=0.1),
                       output=OutputConfig(out=out / "map", rerun=rrd, rerun_map_every=3))
    result = Pipeline(config).run()
    return result, _read_rrd(rrd)


def test_every_frame_logs_its_images_and_camera_pose(logged_run):
    result, entities = logged_run
    assert len(_column(entities["/world/camera/image/rgb"], "EncodedImage:blob")) == FRAMES
    assert len(_column(entities["/world/camera/image/depth"], "DepthImage:buffer")) == FRAMES
    classes = _column(entities["/world/camera/image/classes"], "SegmentationImage:buffer")
    assert len(classes) == FRAMES
    translations = np.array(_column(entities["/world/camera"], "Transform3D:translation")).reshape(FRAMES, 3)
    np.testing.assert_allclose(translations, np.array(result.poses)[:, :3, 3], atol=1e-6)


def test_map_is_logged_every_n_frames_and_at_the_end_in_class_colours(logged_run):
    result, entities = logged_run
    centers = _column(entities["/world/map"], "Boxes3D:centers")
    assert len(centers) == 3  # after frames 3 and 6, and the final map after frame 7
    sizes = [len(c) for c in centers]
    assert sizes == sorted(sizes)  # the map grows
    cloud = result.maps[0].cloud()
    np.testing.assert_allclose(np.array(centers[-1]).reshape(-1, 3), cloud.centers, atol=1e-6)
    colors = np.array(_column(entities["/world/map"], "Boxes3D:colors")[-1], dtype=np.uint32)
    rgba = np.stack([(colors >> 24) & 255, (colors >> 16) & 255, (colors >> 8) & 255], axis=1)
    np.testing.assert_array_equal(rgba, class_colors(cloud, room_label_set()))
    ids = np.array(_column(entities["/world/map"], "Boxes3D:class_ids")[-1])
    np.testing.assert_array_equal(ids, cloud.labels)
    trajectory = _column(entities["/world/trajectory"], "LineStrips3D:strips")[-1]
    assert len(trajectory[0]) == FRAMES
    assert "AnnotationContext:context" in entities["/world"][0].schema.names or any(
        "AnnotationContext:context" in b.schema.names for b in entities["/world"])


def test_a_run_without_rerun_uses_the_null_visualizer(tmp_path):
    assert isinstance(get_visualizer(OutputConfig(out=tmp_path)), NoVisualizer)


@pytest.mark.slow
def test_semmap_view_writes_a_finished_map_for_rerun(logged_run, tmp_path):
    result, _ = logged_run
    for name in ("map.semmap", "map.ot"):
        rrd = tmp_path / f"{name}.rrd"
        r = run_cli("view", str(result.out_dir / name), "--save", str(rrd))
        assert r.returncode == 0, r.stderr
        centers = np.array(_column(_read_rrd(rrd)["/world/map"], "Boxes3D:centers")[0]).reshape(-1, 3)
        if name == "map.semmap":
            np.testing.assert_allclose(centers, result.maps[0].cloud().centers, atol=1e-6)
        else:  # the .ot holds the pruned tree's occupied leaves, expanded to finest cells: the same voxels
            assert len(centers) == result.report["occupied_voxels"]
    r = run_cli("view", str(result.out_dir / "report.json"), "--save", str(tmp_path / "x.rrd"))
    assert r.returncode == 1 and "not a JSON file semmap view shows" in r.stderr  # a report is no map


@pytest.mark.slow
def test_spawning_a_viewer_without_a_display_is_one_clear_line(room, tmp_path):
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-m", "semmap.cli", "run", str(room), "--out", str(tmp_path / "o"),
                        "--rerun-spawn"], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 1 and "--rerun-spawn: cannot open a rerun viewer: no display" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "o").exists()


@pytest.mark.slow
def test_objects_are_logged_as_labelled_boxes_when_the_run_builds_them(tmp_path):
    from object_helpers import box_frames
    from semmap.config import ObjectsConfig
    from semmap.labels import INDOOR_LABELS
    from semmap.runner import run_config

    chair, table = INDOOR_LABELS.id_of("chair"), INDOOR_LABELS.id_of("table")
    boxes = [(np.array([-0.2, -0.8, 0.0]), np.array([0.2, -0.4, 0.8])),
             (np.array([0.2, 0.9, 0.0]), np.array([1.2, 1.5, 0.75]))]
    write_tum_sequence(tmp_path / "seq", box_frames(boxes, [chair, table], 16), label_set=INDOOR_LABELS)
    rrd = tmp_path / "objects.rrd"
    config = RunConfig(input=InputConfig(dataset=tmp_path / "seq"), mapping=MappingConfig(resolution=0.05),
                       objects=ObjectsConfig(instances="oracle"),
                       output=OutputConfig(out=tmp_path / "out", plots=False, rerun=rrd, rerun_map_every=8))
    result = run_config(config)
    labels = _column(_read_rrd(rrd)["/world/objects"], "Boxes3D:labels")[-1]
    objects = json.loads((result.out_dir / "objects.json").read_text())["objects"]
    assert len(labels) == len(objects) > 0
    assert sorted(labels) == sorted(f"{o['id']} {o['class']}" for o in objects)
