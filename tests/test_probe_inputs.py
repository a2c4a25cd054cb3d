"""Issue 31, the input-side cases of the 2026-11-25 probe (S2-S6, S14-S16, U1-U24, M5, M10, H1/M3/U21): every
damaged or odd input is refused in one line naming the file, frame or option (or skipped with a warning naming it),
with exit code 1 and no traceback, before the work it would spoil. Each fixture is rebuilt here in a few lines."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import room_label_set
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.types import Observation, TopKProbs


def cli(capsys, monkeypatch, *args: object) -> tuple[int, str, str]:
    """Run ``semmap ARGS`` in this process as the console script does: (exit code, stdout, stderr)."""
    from semmap.cli import main

    monkeypatch.setattr(sys, "argv", ["semmap", *map(str, args)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    out, err = capsys.readouterr()
    code = exit_info.value.code
    return (code if isinstance(code, int) else 0 if code is None else 1), out, err


def refused(capsys, monkeypatch, *args: object) -> str:
    """The one-line error of a command that must fail (exit 1, no traceback)."""
    code, out, err = cli(capsys, monkeypatch, *args)
    assert code == 1, (out, err)
    assert "Traceback" not in err + out
    lines = [line for line in err.splitlines() if line.startswith("semmap: error: ")]
    assert len(lines) == 1, err
    return lines[0]


# ---------------------------------------------------------------------------------------------- map files
def _observation() -> Observation:
    rng = np.random.default_rng(0)
    points = rng.uniform([-1, -1, 1], [1, 1, 2], (300, 3)).astype(np.float32)
    sem = TopKProbs.from_hard_labels(rng.integers(0, 7, 300).astype(np.uint16), 0.9, 7)
    return Observation(points, np.zeros(3), np.full((300, 3), 200, np.uint8), sem)


@pytest.fixture(scope="module")
def maps(tmp_path_factory) -> Path:
    """``map.ot``, ``map.bt``, ``map.semmap`` of a tiny OctoMap and ``voxelgrid.semmap``, ``voxelgrid.ply`` of a tiny
    voxel grid."""
    from semmap.io.map_files import save_map_files
    from semmap.maps.voxel_grid import SemanticVoxelGrid

    root = tmp_path_factory.mktemp("maps")
    for m in (SemanticOctoMap(0.1, label_set=room_label_set()),
              SemanticVoxelGrid(0.1, label_set=room_label_set(), free_space=True)):
        m.integrate(_observation())
        save_map_files(m, root)
    return root


def _rewrite_npz(src: Path, dst: Path, **changes) -> Path:
    """A copy of the zip of arrays ``src`` with some arrays (by name) replaced by the functions of their old value."""
    with np.load(src) as z:
        arrays = {name: z[name] for name in z.files}
    for name, change in changes.items():
        arrays[name] = change(arrays[name])
    with open(dst, "wb") as f:
        np.savez_compressed(f, **arrays)
    return dst


def _with_header(src: Path, dst: Path, **fields) -> Path:
    """A copy of a ``.semmap`` with some header fields changed."""
    def change(raw: np.ndarray) -> np.ndarray:
        header = {**json.loads(raw.tobytes()), **fields}
        return np.frombuffer(json.dumps(header).encode(), np.uint8)
    return _rewrite_npz(src, dst, header=change)


def _nan(a: np.ndarray) -> np.ndarray:
    return np.full_like(a, np.nan)


def test_s3_a_voxel_grid_with_nan_log_odds_is_refused_by_info_and_view(maps, tmp_path, capsys, monkeypatch):
    bad = _rewrite_npz(maps / "voxelgrid.semmap", tmp_path / "all_nan_vg.semmap", logodds=_nan)
    for args in (["info", bad], ["view", bad, "--save", tmp_path / "v.rrd"]):
        line = refused(capsys, monkeypatch, *args)
        assert str(bad) in line and "non-finite" in line and "log-odds" in line
    assert not (tmp_path / "v.rrd").exists()


@pytest.mark.parametrize("member", ["dense", "geo_logodds"])
def test_s3_every_float_array_of_a_grid_file_is_checked(maps, tmp_path, capsys, monkeypatch, member):
    from semmap.io.map_files import load_map

    src = maps / "voxelgrid.semmap"
    with np.load(src) as z:
        if member not in z.files or z[member].size == 0:
            pytest.skip(f"this grid has no {member}")
    bad = _rewrite_npz(src, tmp_path / "bad.semmap", **{member: _nan})
    with pytest.raises(Exception, match=r"bad\.semmap: .*non-finite"):
        load_map(bad)


def test_s4_a_ply_with_nan_coordinates_is_refused(maps, tmp_path, capsys, monkeypatch):
    data = bytearray((maps / "voxelgrid.ply").read_bytes())
    start = data.index(b"end_header\n") + len(b"end_header\n")
    data[start:start + 4] = np.float32(np.nan).tobytes()  # the first vertex's x
    bad = tmp_path / "ply_nan.ply"
    bad.write_bytes(bytes(data))
    for args in (["info", bad], ["view", bad, "--save", tmp_path / "v.rrd"]):
        line = refused(capsys, monkeypatch, *args)
        assert str(bad) in line and "non-finite" in line


@pytest.mark.parametrize("res", ["1e+300", "1e-300", "11.0"])
@pytest.mark.parametrize("name", ["map.ot", "map.bt"])
def test_s5_an_octomap_file_resolution_outside_the_limits_is_refused(maps, tmp_path, capsys, monkeypatch, res,
                                                                   name):
    bad = tmp_path / f"res{res}{Path(name).suffix}"
    bad.write_bytes((maps / name).read_bytes().replace(b"res 0.1\n", f"res {res}\n".encode(), 1))
    for args in (["info", bad], ["view", bad, "--save", tmp_path / "v.rrd"]):
        line = refused(capsys, monkeypatch, *args)
        assert str(bad) in line and "resolution must be from 0.001 to 10" in line


@pytest.mark.parametrize("name", ["map.semmap", "voxelgrid.semmap"])
def test_u22_a_semmap_resolution_outside_the_limits_names_the_file(maps, tmp_path, capsys, monkeypatch, name):
    bad = _with_header(maps / name, tmp_path / "res_huge.semmap", resolution=1e308)
    line = refused(capsys, monkeypatch, "info", bad)
    assert str(bad) in line and "resolution must be from 0.001 to 10" in line


def test_the_good_map_files_still_read(maps, capsys, monkeypatch):
    for name in ("map.ot", "map.bt", "map.semmap", "voxelgrid.semmap", "voxelgrid.ply"):
        code, _out, err = cli(capsys, monkeypatch, "info", maps / name)
        assert code == 0, err
