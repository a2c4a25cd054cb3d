"""The semantic mesh (issue 35): the TSDF's ray integration puts the zero crossing on the surface, marching cubes
gives a closed, consistently oriented surface, and ``semmap run --maps octomap,tsdf`` writes a ``mesh.ply`` that
Open3D and plyfile read, whose vertices carry the class of the OctoMap voxel they lie in."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from semmap.cli import app
from semmap.errors import ConfigError, FormatError
from semmap.io.map_files import load_map, save_map
from semmap.keys import keys_to_coords, pack_keys
from semmap.maps.mesh import semantic_mesh, voxel_of_vertex
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.maps.tsdf import TsdfMap
from semmap.types import EMPTY_LABEL, LabelSet

RES = 0.05


def sphere_tsdf(radius: float = 0.5, trunc: float = 4.0) -> TsdfMap:
    """A TSDF holding the exact truncated distance of a sphere at the origin, in a band around it."""
    m = TsdfMap(RES, truncation=trunc)
    n = int(np.ceil((radius + trunc * RES) / RES)) + 1
    keys = np.stack(np.meshgrid(*[np.arange(-n, n) + 32768] * 3, indexing="ij"), -1).reshape(-1, 3)
    d = np.linalg.norm(keys_to_coords(keys, RES), axis=1) - radius
    band = np.abs(d) < trunc * RES
    m.load_field(pack_keys(keys[band]), d[band].astype(np.float32), np.ones(band.sum(), np.int32))
    return m


def edge_uses(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How many triangles use each undirected edge, and each directed one."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return (np.unique(np.sort(directed, 1), axis=0, return_counts=True)[1],
            np.unique(directed, axis=0, return_counts=True)[1])


def test_marching_cubes_gives_a_closed_outward_surface_on_the_zero_crossing():
    v, f = sphere_tsdf().mesh()
    undirected, directed = edge_uses(f)
    assert len(f) > 1000 and np.all(undirected == 2) and np.all(directed == 1)  # closed, consistently oriented
    assert np.abs(np.linalg.norm(v, axis=1) - 0.5).max() < 0.1 * RES  # linear interpolation on a 5 cm grid
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all((n * v[f].mean(1)).sum(1) > 0)  # counter-clockwise seen from outside (the free side)
    assert len(np.unique(f)) == len(v)  # every vertex in a triangle, none twice (one per cut voxel edge)


def test_rays_put_the_surface_on_the_wall_and_face_the_sensor():
    rng = np.random.default_rng(0)
    m = TsdfMap(RES, truncation=3)
    for seed in range(3):  # a wall at x = 2 m seen from near the origin
        pts = np.column_stack([np.full(4000, 2.0), rng.uniform(-0.6, 0.6, (4000, 2))])
        m.integrate_rays(pts, np.array([0.0, 0.05 * seed, 0.0]))
    packed, sdf, weight = m.field()
    x = keys_to_coords(np.stack([packed & 0xFFFF, (packed >> 16) & 0xFFFF, (packed >> 32) & 0xFFFF], 1), RES)[:, 0]
    assert np.all(weight >= 1) and np.all(np.abs(sdf) <= 3 * RES + 1e-6)
    assert np.all(np.sign(sdf[np.abs(x - 2.0) > RES]) == np.sign(2.0 - x[np.abs(x - 2.0) > RES]))
    v, f = m.mesh()
    centre = np.all(np.abs(v[:, 1:]) < 0.4, axis=1)
    assert centre.sum() > 100 and np.abs(v[centre, 0] - 2.0).max() < RES / 2
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(n[:, 0] < 0)  # towards the sensor
    with pytest.raises(ConfigError, match="--tsdf-truncation"):
        TsdfMap(RES, truncation=0.5)


def test_a_vertex_takes_its_voxels_class_else_the_nearest_occupied_neighbour():
    labels = LabelSet.generic(4)
    m = SemanticOctoMap(RES, label_set=labels)
    occupied = np.array([[1.025, 0.025, 0.025], [1.125, 0.025, 0.025]])  # two voxels, classes 1 and 2
    from semmap.types import Observation, TopKProbs

    sem_l = np.full((2, 3), EMPTY_LABEL, np.uint16)
    sem_l[:, 0] = (1, 2)
    sem_p = np.zeros((2, 3), np.float32)
    sem_p[:, 0] = 0.9
    m.integrate(Observation(occupied.astype(np.float32), np.zeros(3), np.full((2, 3), 100, np.uint8),
                            TopKProbs(sem_l, sem_p)))
    vertices = np.array([[1.01, 0.01, 0.01],  # in voxel 1
                         [1.09, 0.01, 0.01],  # in the free voxel between: nearer voxel 2's centre (1.125)
                         [1.06, 0.01, 0.01],  # between: nearer voxel 1's centre
                         [1.5, 0.5, 0.5]])  # far from both
    idx, own = voxel_of_vertex(vertices, m)
    cloud = m.cloud()
    assert own.tolist() == [True, False, False, False]
    got = [int(cloud.labels[i]) if i >= 0 else None for i in idx]
    assert got == [1, 2, 1, None]
    assert m.class_at(vertices[:1])[0][0] == 1 and m.class_at(vertices[1:2])[0][0] == EMPTY_LABEL


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    """A 3-frame simulated kitchen at 80x60 pixels mapped with --maps octomap,tsdf."""
    root = tmp_path_factory.mktemp("mesh")
    runner = CliRunner()
    r = runner.invoke(app, ["simulate", "--out", str(root / "seq"), "--frames", "3", "--kind", "kitchen",
                            "--size", "small", "--image-size", "80x60"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["run", str(root / "seq"), "--out", str(root / "out"), "--resolution", "0.05",
                            "--maps", "octomap,tsdf", "--tsdf-truncation", "3"])
    assert r.exit_code == 0, r.output
    return root / "out"


@pytest.mark.slow
def test_run_writes_a_mesh_open3d_and_plyfile_read_with_the_octomaps_classes(run_folder):
    import open3d as o3d
    import plyfile

    ply = plyfile.PlyData.read(str(run_folder / "mesh.ply"))
    vert, faces = ply["vertex"], np.vstack(ply["face"]["vertex_indices"])
    legacy = o3d.io.read_triangle_mesh(str(run_folder / "mesh.ply"))
    assert len(legacy.vertices) == len(vert) > 100 and len(legacy.triangles) == len(faces) > 100
    assert np.allclose(np.asarray(legacy.vertices), np.stack([vert["x"], vert["y"], vert["z"]], 1))
    assert legacy.has_vertex_colors() and faces.max() < len(vert)
    labels = LabelSet.load(run_folder.parent / "seq" / "labelset.json")
    names = [p.name for p in vert.properties]
    assert names[:8] == ["x", "y", "z", "red", "green", "blue", "label", "confidence"]
    assert names[8:] == [f"prob_{c}" for c in range(len(labels))]
    probs = np.stack([vert[f"prob_{c}"] for c in range(len(labels))], 1)
    has = vert["label"] != EMPTY_LABEL
    assert has.mean() > 0.9 and np.allclose(probs[has].sum(1), 1.0, atol=1e-3)
    assert np.array_equal(probs[has].argmax(1), vert["label"][has])
    # the measure of issue 35: vertices in an occupied OctoMap voxel carry that voxel's class (class_at)
    octomap = load_map(run_folder / "map.semmap")
    pts = np.stack([vert["x"], vert["y"], vert["z"]], 1).astype(np.float64)
    cls, conf = octomap.class_at(pts)
    inside = cls != EMPTY_LABEL
    assert inside.mean() > 0.5 and np.array_equal(vert["label"][inside], cls[inside])
    assert np.allclose(vert["confidence"][inside], conf[inside])
    report = json.loads((run_folder / "report.json").read_text())
    assert report["maps"]["tsdf"]["truncation_voxels"] == 3.0 and "mesh.ply" in report["maps"]["tsdf"]["files"]


def test_export_mesh_rebuilds_the_runs_mesh_and_refuses_a_folder_without_tsdf(run_folder, tmp_path):
    r = CliRunner().invoke(app, ["export", "mesh", str(run_folder), "--out", str(tmp_path / "m")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "m" / "mesh.ply").read_bytes() == (run_folder / "mesh.ply").read_bytes()
    summary = json.loads((tmp_path / "m" / "mesh.json").read_text())
    assert summary["labels_from"] == "octomap" and summary["classified_share"] > 0.9
    from semmap.products.export import export_mesh

    with pytest.raises(FormatError, match="--maps octomap,tsdf"):
        export_mesh(run_folder / "map.semmap", tmp_path / "x")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FormatError, match=r"no tsdf\.semmap"):
        export_mesh(tmp_path / "empty", tmp_path / "y")


def test_a_saved_tsdf_loads_back_with_the_same_field_and_mesh(tmp_path):
    m = sphere_tsdf(trunc=3)
    save_map(tmp_path / "t.semmap", m)
    back = load_map(tmp_path / "t.semmap")
    assert isinstance(back, TsdfMap) and back.truncation == 3.0
    for a, b in zip(m.field(), back.field(), strict=True):
        assert np.array_equal(a, b)
    mesh = semantic_mesh(back)  # no semantic voxels: nothing classified, grey
    assert len(mesh) == len(m.mesh()[0]) and np.all(mesh.labels == EMPTY_LABEL) and mesh.probs is None
    assert np.all(mesh.colors == 128)
