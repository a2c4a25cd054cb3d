"""Robot products (issue 35): the navigation grid and costmap in the ROS map_server format, the exact signed
distance field against scipy's, its incremental update against a full recompute, and `semmap export`."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from semmap.cli import app
from semmap.errors import ConfigError, FormatError, OutputError
from semmap.io.map_files import save_map
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.products._edt_kernels import squared_edt
from semmap.products.esdf import IncrementalEsdf, esdf_of
from semmap.products.export import export_grid, load_esdf
from semmap.products.map_server import read_as_map_server
from semmap.products.navgrid import LETHAL, GridOptions, navigation_grid
from semmap.products.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyVolume, occupancy_volume
from semmap.types import EMPTY_LABEL, LabelSet, Observation, TopKProbs

RES = 0.1
LABELS = LabelSet(("unknown", "floor", "chair", "person"), np.array([[0, 0, 0], [90, 160, 90], [200, 200, 0],
                                                                      [220, 40, 40]], np.uint8))
FLOOR, CHAIR, PERSON = 1, 2, 3


def _block(lo, hi, label):
    axes = [np.arange(a + RES / 2, b, RES) for a, b in zip(lo, hi, strict=True)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return pts, np.full(len(pts), label, np.uint16)


def room_map() -> SemanticOctoMap:
    """A 2 m x 2 m floor (z 0..0.1), a chair block and a person column, seen from three points above the floor."""
    parts = [_block((0, 0, 0), (2, 2, 0.1), FLOOR), _block((1.0, 1.0, 0.2), (1.2, 1.2, 0.6), CHAIR),
             _block((0.4, 1.5, 0.2), (0.5, 1.6, 1.0), PERSON)]
    pts = np.concatenate([p for p, _ in parts]).astype(np.float32)
    lab = np.concatenate([la for _, la in parts])
    m = SemanticOctoMap(RES, label_set=LABELS)
    labels = np.full((len(lab), 3), EMPTY_LABEL, np.uint16)
    probs = np.zeros((len(lab), 3), np.float32)
    labels[:, 0], probs[:, 0] = lab, 0.9
    sem = TopKProbs(labels, probs)
    for origin in ([1.0, 0.5, 1.7], [0.5, 1.0, 1.7], [1.6, 1.6, 1.7]):
        m.integrate(Observation(pts, np.array(origin), np.full((len(pts), 3), 120, np.uint8), sem))
    return m


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> tuple[SemanticOctoMap, object]:
    m = room_map()
    path = tmp_path_factory.mktemp("room") / "map.semmap"
    save_map(path, m)
    return m, path


def cell(grid, x, y) -> int:
    i, j = np.floor((np.array([x, y]) - grid.origin) / grid.resolution).astype(int)
    return int(grid.occupancy[i, j])


# ------------------------------------------------------------------ the volume and the grid
def test_volume_has_the_map_states_and_classes(room):
    v = occupancy_volume(room[0])
    i = v.index_of(np.array([[1.05, 1.05, 0.35], [1.0, 0.5, 1.0], [0.05, 0.05, 0.05]]))
    assert v.state[tuple(i[0])] == OCCUPIED and v.labels[tuple(i[0])] == CHAIR
    assert v.state[tuple(i[1])] == FREE and v.labels[tuple(i[1])] == EMPTY_LABEL
    assert v.labels[tuple(i[2])] == FLOOR


def test_grid_cells_follow_the_band_and_classes(room):
    v = occupancy_volume(room[0], (np.array([-0.5, -0.5, -0.1]), np.array([2.5, 2.5, 1.8])))
    g = navigation_grid(v)
    assert g.floor_z == pytest.approx(0.1)  # detected from the floor class
    assert cell(g, 1.05, 1.05) == LETHAL  # the chair is in the band
    assert cell(g, 1.0, 0.5) == 0  # seen free above the floor
    assert cell(g, -0.4, -0.4) == -1  # never seen: unknown stays unknown
    low = navigation_grid(v, GridOptions(z_min=0.7, z_max=1.5))  # a band above the chair
    assert cell(low, 1.05, 1.05) == 0 and cell(low, 0.45, 1.55) == LETHAL
    nogo = navigation_grid(v, GridOptions(z_min=0.7, z_max=1.5, no_go=("chair",), costs={"person": 50}))
    assert cell(nogo, 1.05, 1.05) == LETHAL and nogo.classes == {"chair": 4, "person": 1}
    wide = navigation_grid(v, GridOptions(inflation=0.2))
    i, j = np.floor((np.array([0.85, 1.05]) - wide.origin) / RES).astype(int)
    assert wide.occupancy[i, j] == 0 and wide.cost[i, j] == 99  # inflated in the costmap only


def test_grid_options_refuse_nonsense(room):
    v = occupancy_volume(room[0])
    with pytest.raises(ConfigError, match="--z-max"):
        GridOptions(z_min=1.0, z_max=0.5)
    with pytest.raises(ConfigError, match="finite"):
        GridOptions(z_min=float("nan"))
    with pytest.raises(ConfigError, match="stairs not in the map's classes"):
        navigation_grid(v, GridOptions(no_go=("stairs",)))
    with pytest.raises(ConfigError, match="holds no voxel"):
        navigation_grid(v, GridOptions(floor=50.0))


def test_export_grid_follows_map_server(room, tmp_path):
    """map.yaml has exactly map_server's fields, and map_server's reading of the images gives back the grid."""
    _, path = room
    out = tmp_path / "grid"
    export_grid(path, out, GridOptions(z_min=0.7, costs={"chair": 50}, inflation=0.1))  # the chair below the band
    spec = yaml.safe_load((out / "map.yaml").read_text())
    assert set(spec) == {"image", "mode", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"}
    assert spec["image"] == "map.pgm" and spec["mode"] == "trinary" and spec["negate"] == 0
    assert spec["resolution"] == RES and 0 < spec["free_thresh"] < spec["occupied_thresh"] < 1
    raw = (out / "map.pgm").read_bytes()
    assert raw.startswith(b"P5\n")
    image = cv2.imread(str(out / "map.pgm"), cv2.IMREAD_UNCHANGED)
    summary = json.loads((out / "grid.json").read_text())
    assert image.shape == tuple(summary["size_cells"][::-1])
    assert spec["origin"][:2] == pytest.approx(summary["origin"]) and spec["origin"][2] == 0.0
    cells = read_as_map_server(image, None, spec["mode"], spec["occupied_thresh"], spec["free_thresh"])
    assert {k: int((cells == v).sum()) for k, v in (("occupied", 100), ("free", 0), ("unknown", -1))} == \
        summary["cells"]
    cspec = yaml.safe_load((out / "costmap.yaml").read_text())
    rgba = cv2.imread(str(out / "costmap.png"), cv2.IMREAD_UNCHANGED)
    costs = read_as_map_server(rgba[..., :3].mean(axis=2), rgba[..., 3], cspec["mode"], cspec["occupied_thresh"],
                               cspec["free_thresh"])
    exact = np.load(out / "costmap.npy")
    assert np.abs(costs.astype(int) - exact).max() <= 1 and (costs == -1).sum() == (exact == -1).sum()
    assert 50 in exact and 99 in exact


def test_export_refuses_unsafe_outputs(room, tmp_path):
    _, path = room
    with pytest.raises(OutputError):
        export_grid(path, path, GridOptions())
    with pytest.raises(OutputError):
        export_grid(path, path.parent, GridOptions())  # the folder holding the map
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="holds other files"):
        export_grid(path, tmp_path / "busy", GridOptions())
    with pytest.raises(FormatError, match=r"\.semmap file beside it"):
        export_grid(path.with_suffix(".ot"), tmp_path / "x", GridOptions())


# ------------------------------------------------------------------ the distance field
@settings(max_examples=25, deadline=None, derandomize=True)
@given(st.tuples(st.integers(1, 9), st.integers(1, 9), st.integers(1, 9)), st.integers(0, 2**31 - 1),
       st.floats(0.0, 0.3))
def test_squared_edt_is_exact(shape, seed, density):
    sites = np.random.default_rng(seed).random(shape) < density
    got = squared_edt(sites)
    if not sites.any():
        assert np.all(got >= 1e29)
        return
    assert np.abs(got - ndimage.distance_transform_edt(~sites) ** 2).max() < 1e-3


def test_esdf_signed_and_queries(room):
    v = occupancy_volume(room[0])
    e = esdf_of(v)
    occ = v.state == OCCUPIED
    ref = np.where(occ, -ndimage.distance_transform_edt(occ), ndimage.distance_transform_edt(~occ)) * RES
    assert np.abs(e.distance - ref).max() < 1e-6
    centers = v.origin + np.argwhere(np.ones(v.shape, bool))[::97] * RES
    assert np.allclose(e.distance_at(centers), e.distance.ravel()[::97], atol=1e-6)
    p = np.array([[1.12, 0.83, 0.43]])  # beside the chair (x 1.0-1.2, y 1.0-1.2): the field grows away from it
    g = e.gradient_at(p)[0]
    h = 1e-4
    fd = [(e.distance_at(p + h * d) - e.distance_at(p - h * d))[0] / (2 * h) for d in np.eye(3)]
    assert np.allclose(g, fd, atol=1e-3) and g[1] < 0
    with pytest.raises(ConfigError, match="finite"):
        e.distance_at(np.array([[np.nan, 0, 0]]))


@pytest.mark.slow
def test_incremental_matches_full_recompute():
    rng = np.random.default_rng(3)
    shape = (24, 20, 12)
    occ = np.zeros(shape, bool)
    occ[:, :, 1] = True
    inc = IncrementalEsdf(shape, RES, np.zeros(3), max_distance=0.8)
    for step in range(6):
        occ = occ.copy()
        i, j, k = rng.integers(0, 18), rng.integers(0, 15), rng.integers(2, 8)
        occ[i:i + 5, j:j + 4, k:k + 3] = step % 2 == 0  # add a box, then carve one out
        occ.ravel()[rng.choice(occ.size, 20)] ^= True
        inc.update(occ)
        ref = np.sqrt(ndimage.distance_transform_edt(~occ) ** 2) * RES
        ref[ref > 0.8 + 1e-9] = np.inf
        got = inc.distance()
        assert np.array_equal(np.isfinite(got), np.isfinite(ref))
        fin = np.isfinite(ref)
        assert np.abs(got[fin] - ref[fin]).max() <= RES / 2  # site propagation: exact but for rare cases
        assert np.abs(got[fin] - ref[fin]).mean() < 1e-3


def test_export_esdf_command(room, tmp_path):
    from typer.testing import CliRunner

    _, path = room
    out = tmp_path / "esdf"
    r = CliRunner().invoke(app, ["export", "esdf", str(path), "--out", str(out)])
    assert r.exit_code == 0, r.output
    e = load_esdf(out)
    assert e.resolution == RES and (out / "esdf_slice.png").stat().st_size > 1000
    assert json.loads((out / "esdf.json").read_text())["size_voxels"] == list(e.distance.shape)
    r = CliRunner().invoke(app, ["export", "grid", str(path), "--out", str(tmp_path / "g"), "--cost", "chair=x"])
    assert r.exit_code != 0 and "CLASS=COST" in str(r.exception)


def test_volume_from_empty_map_refused():
    with pytest.raises(ConfigError, match="nothing to export"):
        occupancy_volume(SemanticOctoMap(RES))
    v = OccupancyVolume(np.full((2, 2, 2), UNKNOWN, np.int8), np.full((2, 2, 2), EMPTY_LABEL, np.uint16),
                        np.zeros(3), RES)
    with pytest.raises(ConfigError, match="floor"):
        navigation_grid(v)
