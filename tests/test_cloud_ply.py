"""Issue 33, item 6: a run asked for it (``--cloud``, ``output.cloud``) writes the voxel-filtered coloured point
cloud as a real binary PLY (``cloud.ply``) and the report gives its real size in bytes beside the map files (no
longer points x 15 bytes); by default (issue 47) a run writes none and spends no time on it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from plyfile import PlyData

from helpers import make_room_frames, room_label_set
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
from semmap.io.ply import write_colored_cloud_ply
from semmap.io.tum_writer import write_tum_sequence
from semmap.pipeline import Pipeline


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("room-cloud")
    write_tum_sequence(root, make_room_frames(4), label_set=room_label_set())
    return root


def _run(room, out, **output):
    return Pipeline(RunConfig(input=InputConfig(dataset=room), mapping=MappingConfig(resolution=0.1,
                                                                                     point_resolution=0.05),
                              output=OutputConfig(out=out, plots=False, preview=False, **output))).run()


def test_the_run_writes_cloud_ply_and_reports_its_real_size(room, tmp_path_factory):
    out = tmp_path_factory.mktemp("cloud-out") / "out"
    result = _run(room, out, cloud=True)
    path = out / "cloud.ply"
    ply = PlyData.read(str(path))
    v = ply["vertex"]
    assert [p.name for p in v.properties] == ["x", "y", "z", "red", "green", "blue"]
    assert ply.text is False and ply.byte_order == "<"
    report = json.loads((out / "report.json").read_text())
    size = path.stat().st_size
    assert report["dense_point_cloud_bytes"] == size == report["bytes_on_disk"]["cloud.ply"]
    assert report["dense_point_cloud_points"] == len(v) > 100 and report["dense_point_cloud_cell_m"] == 0.05
    assert len(v) < report["points_integrated"]  # voxel-filtered: one point per 5 cm cell, not every pixel
    xyz = np.stack([v["x"], v["y"], v["z"]], 1)
    keys = np.floor(xyz / 0.05 + 1e-3).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(v)  # one point per cell
    rgb = np.stack([v["red"], v["green"], v["blue"]], 1)
    assert rgb.std() > 0  # coloured from the frames
    md = (out / "report.md").read_text()
    assert f"{size:,} |" in md and f"cloud.ply, binary PLY: {len(v):,} points, one per 0.05 m cell" in md
    assert f"{report['bytes_on_disk']['map.bt']:,} |" in md and f"{report['bytes_on_disk']['map.ot']:,} |" in md
    assert result.files["cloud.ply"] == path


def test_by_default_a_run_writes_no_cloud_reports_none_and_times_none(room, tmp_path_factory):
    out = tmp_path_factory.mktemp("no-cloud-out") / "out"
    _run(room, out)
    report = json.loads((out / "report.json").read_text())
    assert not (out / "cloud.ply").exists() and "dense_point_cloud_bytes" not in report
    assert "cloud" not in report["ms_per_frame"]


def test_colored_cloud_ply_round_trips_through_plyfile(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3))
    rgb = rng.integers(0, 256, (50, 3)).astype(np.uint8)
    size = write_colored_cloud_ply(tmp_path / "c.ply", pts, rgb, comment="test")
    v = PlyData.read(str(tmp_path / "c.ply"))["vertex"]
    assert size == (tmp_path / "c.ply").stat().st_size and size > 50 * 15
    np.testing.assert_allclose(np.stack([v["x"], v["y"], v["z"]], 1), pts.astype(np.float32))
    assert np.array_equal(np.stack([v["red"], v["green"], v["blue"]], 1), rgb)


@pytest.mark.slow
def test_a_resumed_run_writes_the_same_cloud(room, tmp_path):
    """The cloud is part of the mapper's checkpoint: a run killed after three frames and resumed writes the same
    cloud.ply as one that never stopped."""

    def stop_after_three(it, total):
        for i, item in enumerate(it):
            if i == 3:
                raise KeyboardInterrupt
            yield item

    config = RunConfig(input=InputConfig(dataset=room), mapping=MappingConfig(resolution=0.1, point_resolution=0.05),
                       output=OutputConfig(out=tmp_path / "resumed", plots=False, preview=False, cloud=True))
    with pytest.raises(KeyboardInterrupt):
        Pipeline(config, checkpoint_every=1, progress=stop_after_three).run()
    Pipeline(config, resume=True).run()
    _run(room, tmp_path / "whole", cloud=True)
    assert (tmp_path / "resumed" / "cloud.ply").read_bytes() == (tmp_path / "whole" / "cloud.ply").read_bytes()
