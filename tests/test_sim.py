"""The simulator: scenes, meshes, rendering, noise, trajectories, ground truth and the TUM export."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial import ConvexHull

from semmap.errors import SimulationError
from semmap.keys import coords_to_keys
from semmap.labels import INDOOR_LABELS
from semmap.sim.export import simulate_sequence
from semmap.sim.ground_truth import gt_objects, gt_voxels
from semmap.sim.noise import KinectNoise
from semmap.sim.render import Renderer, center_depths, scene_raycaster
from semmap.sim.scene import KINDS, generate_scene
from semmap.sim.trajectory import TRAJECTORY_KINDS, look_at, make_trajectory
from semmap.types import DEFAULT_INTRINSICS

SMALL = DEFAULT_INTRINSICS.scaled(0.5)  # 320 x 240, for tests that do not need full resolution
#: Interpenetration below this depth (metres) counts as touching.
PENETRATION_TOL = 1e-3


@pytest.fixture(scope="module")
def office():
    return generate_scene(0, "office", "medium")


@pytest.fixture(scope="module")
def office_views(office):
    poses = make_trajectory(office, "loop", 45, seed=0)
    return poses[::9]


# --------------------------------------------------------------------------------------------------
# labels and arguments
# --------------------------------------------------------------------------------------------------
def test_label_set_is_distinct_never_white_and_nyu_like():
    names = INDOOR_LABELS.names
    assert names[0] == "unknown"
    for needed in ("wall", "floor", "ceiling", "door", "window", "table", "chair", "sofa", "bed", "cabinet",
                   "shelf", "desk", "monitor", "keyboard", "book", "cup", "bottle", "plant", "lamp", "picture",
                   "pillow", "box", "person"):
        assert needed in names
    colors = INDOOR_LABELS.colors.astype(int)
    assert len({tuple(c) for c in colors}) == len(colors)
    assert not np.any(np.all(colors == 255, axis=1))
    d = np.linalg.norm(colors[:, None] - colors[None], axis=2) + np.eye(len(colors)) * 999
    assert d.min() > 20


@pytest.mark.parametrize("call", [
    lambda: generate_scene(0, "garage"),
    lambda: generate_scene(0, "office", "huge"),
    lambda: generate_scene(-1),
])
def test_bad_scene_arguments_raise(call):
    with pytest.raises(SimulationError):
        call()


def test_bad_trajectory_and_export_arguments_raise(office, tmp_path):
    with pytest.raises(SimulationError):
        make_trajectory(office, "spiral", 10, 0)
    with pytest.raises(SimulationError):
        make_trajectory(office, "loop", 0, 0)
    with pytest.raises(SimulationError):
        simulate_sequence(tmp_path, frames=0)
    with pytest.raises(SimulationError):
        Renderer(office, backend="opengl")


# --------------------------------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------------------------------
def test_scene_arrays_and_objects_are_consistent(office):
    s = office
    assert s.vertices.dtype == np.float32 and s.vertices.shape[1] == 3
    assert s.triangles.dtype == np.int32 and s.triangles.max() < len(s.vertices)
    T = len(s.triangles)
    assert s.tri_class.shape == s.tri_instance.shape == s.tri_material.shape == (T,)
    assert s.tri_material.max() < len(s.materials)
    ids = [o.instance_id for o in s.objects]
    assert ids == sorted(set(ids)) and min(ids) >= 1
    for o in s.objects:
        tris = s.tri_instance == o.instance_id
        assert tris.any(), o
        assert np.all(s.tri_class[tris] == o.class_id)
        assert INDOOR_LABELS.names[o.class_id] == o.class_name
        assert np.all(o.bbox_min <= o.centroid + 1e-6) and np.all(o.centroid <= o.bbox_max + 1e-6)
    stuff = s.tri_instance == 0
    assert set(np.unique(s.tri_class[stuff])) == {INDOOR_LABELS.id_of(n) for n in ("wall", "floor", "ceiling")}
    json.dumps(s.params)
    assert gt_objects(s) == s.objects


def test_same_seed_same_scene_and_different_seed_differs():
    a, b = generate_scene(3, "kitchen", "small"), generate_scene(3, "kitchen", "small")
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.tri_class, b.tri_class)
    c = generate_scene(4, "kitchen", "small")
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)


@pytest.mark.slow
def test_kinds_cover_at_least_15_object_classes_with_plausible_placement():
    classes = set()
    for i, kind in enumerate(KINDS):
        s = generate_scene(i, kind, "medium")
        classes |= {o.class_name for o in s.objects}
        # small things rest on something: on a support or on the floor only if they are floor objects
        for child, parent in s.supports.items():
            c, p = s.object(child), s.object(parent)
            assert c.bbox_min[2] >= p.bbox_min[2] - 1e-6
    assert len(classes) >= 15, classes
    for needed in ("chair", "monitor", "keyboard", "book", "picture", "door", "window"):
        assert needed in classes


def test_second_room_is_connected_by_a_doorway():
    s = generate_scene(1, "office", "medium", second_room=True)
    assert len(s.rooms) == 2 and len(s.openings) == 1
    lo, hi = s.openings[0]
    mid = 0.5 * (lo + hi)
    assert s.inside_rooms(mid[None])[0]
    # the passage is open: a ray along it from room to room hits nothing before the far room's wall
    start = np.array([s.rooms[0].bounds_max[0] - 0.5, mid[1], 1.2])
    T = look_at(start, start + np.array([1.0, 0.0, 0.0]))
    d = center_depths(scene_raycaster(s), T[None])[0]
    assert d > 0.5 + (s.rooms[1].bounds_min[0] - s.rooms[0].bounds_max[0])


def _hull_equations(points: np.ndarray) -> np.ndarray:
    return ConvexHull(points, qhull_options="QJ").equations


def _surface_samples(points: np.ndarray, rng: np.random.Generator, n: int = 120) -> np.ndarray:
    hull = ConvexHull(points, qhull_options="QJ")
    tri = hull.points[hull.simplices]
    w = rng.dirichlet(np.ones(3), n)
    faces = tri[rng.integers(len(tri), size=n)]
    return np.concatenate([points, np.einsum("nk,nkd->nd", w, faces)])


@pytest.mark.slow
@pytest.mark.parametrize("seed,kind,size", [(0, "office", "medium"), (1, "kitchen", "medium"),
                                            (2, "living_room", "large"), (3, "bedroom", "small"),
                                            (4, "office", "small")])
def test_objects_never_interpenetrate(seed, kind, size):
    s = generate_scene(seed, kind, size)
    rng = np.random.default_rng(0)
    inst = np.array([i for i, _ in s.hulls])
    lo = np.array([v.min(0) for _, v in s.hulls])
    hi = np.array([v.max(0) for _, v in s.hulls])
    n_checked = 0
    for a in range(len(s.hulls)):
        cand = np.nonzero(np.all((lo[a] < hi - PENETRATION_TOL) & (hi[a] > lo + PENETRATION_TOL), axis=1)
                          & (inst != inst[a]))[0]
        cand = cand[cand > a]
        if not len(cand):
            continue
        pa = s.hulls[a][1]
        samples_a = _surface_samples(pa, rng)
        eq_a = _hull_equations(pa)
        for b in cand:
            pb = s.hulls[b][1]
            eq_b = _hull_equations(pb)
            depth_ab = -(samples_a @ eq_b[:, :3].T + eq_b[:, 3]).max(1)  # > 0: inside b by that much
            depth_ba = -(_surface_samples(pb, rng) @ eq_a[:, :3].T + eq_a[:, 3]).max(1)
            assert depth_ab.max() < PENETRATION_TOL and depth_ba.max() < PENETRATION_TOL, (
                s.object(inst[a]).class_name, s.object(inst[b]).class_name)
            n_checked += 1
    # every object stays inside the rooms (doors between rooms sit in the wall itself)
    for o in s.objects:
        if o.class_name == "door":
            continue
        inside = [np.all(o.bbox_min >= r.bounds_min - 1e-6) and np.all(o.bbox_max <= r.bounds_max + 1e-6)
                  for r in s.rooms]
        assert any(inside), o


# --------------------------------------------------------------------------------------------------
# rendering and noise
# --------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_render_channels_and_instance_classes(office, office_views):
    r = Renderer(office)
    v = r.render(office_views[0])
    assert v.rgb.shape == (480, 640, 3) and v.rgb.dtype == np.uint8
    assert v.depth.dtype == np.float32 and v.labels.dtype == np.uint16 and v.instances.dtype == np.int32
    assert (v.depth > 0).all() and (v.labels > 0).all()  # a closed room: every pixel sees something
    cls_of = {o.instance_id: o.class_id for o in office.objects}
    things = v.instances > 0
    mapped = np.vectorize(cls_of.get)(v.instances[things])
    assert np.array_equal(mapped, v.labels[things])


@pytest.mark.slow
def test_rasteriser_matches_ray_casting(office, office_views):
    fast = Renderer(office, SMALL, backend="raster")
    ref = Renderer(office, SMALL, backend="raycast")
    for T in office_views:
        a, b = fast.render(T), ref.render(T)
        assert (a.labels == b.labels).mean() > 0.998
        both = (a.depth > 0) & (b.depth > 0)
        assert np.median(np.abs(a.depth - b.depth)[both]) < 1e-5
        assert (np.abs(a.depth - b.depth)[both] < 1e-3).mean() > 0.998


def test_orb_finds_enough_keypoints_on_typical_views(office, office_views):
    r = Renderer(office, noise=True)
    orb = cv2.ORB_create(nfeatures=2000)
    counts = [len(orb.detect(cv2.cvtColor(r.render(T, i).rgb, cv2.COLOR_RGB2GRAY), None))
              for i, T in enumerate(office_views)]
    assert np.median(counts) >= 300, counts


def test_noise_model_range_quantisation_dropouts_and_seeding(office, office_views):
    clean = Renderer(office, SMALL).render(office_views[1])
    noise = KinectNoise(seed=5)
    cos = np.full(clean.depth.shape, 0.9, np.float32)
    a = noise.apply(clean.depth, cos, frame_index=3)
    assert np.array_equal(a, noise.apply(clean.depth, cos, frame_index=3))
    assert not np.array_equal(a, noise.apply(clean.depth, cos, frame_index=4))
    valid = a > 0
    assert 0.5 < valid.mean() < (clean.depth > 0).mean()
    assert a[valid].min() >= noise.min_depth and a[valid].max() <= noise.max_depth
    disparity = noise.focal_px * noise.baseline_m / a[valid] * noise.subpixel
    assert np.abs(disparity - np.round(disparity)).max() < 1e-2  # on 1/8-pixel disparity steps
    err = (a - clean.depth)[valid & (clean.depth > 1.5) & (clean.depth < 2.5)]
    step = 2.0 ** 2 / (noise.focal_px * noise.baseline_m) / noise.subpixel
    assert abs(err.mean()) < 0.01 and 0.5 * noise.sigma(2.0) < err.std() < noise.sigma(2.0) + step
    grazing = noise.apply(clean.depth, np.full_like(cos, 0.1), frame_index=3)  # ~84 degrees incidence
    assert (grazing > 0).sum() == 0
    # too close / too far is invalid
    near_far = noise.apply(np.array([[0.3, 5.0]], np.float32), np.ones((1, 2), np.float32), 0)
    assert (near_far == 0).all()


# --------------------------------------------------------------------------------------------------
# trajectories
# --------------------------------------------------------------------------------------------------
def _inside_any_hull(scene, points: np.ndarray, margin: float) -> np.ndarray:
    out = np.zeros(len(points), bool)
    for _, v in scene.hulls:
        lo, hi = v.min(0) - margin, v.max(0) + margin
        near = np.all((points > lo) & (points < hi), axis=1)
        if near.any():
            eq = _hull_equations(v)
            out[near] |= (points[near] @ eq[:, :3].T + eq[:, 3]).max(1) < margin
    return out


_SCENES: dict = {}


def _scene(*args):
    if args not in _SCENES:
        _SCENES[args] = generate_scene(*args)
    return _SCENES[args]


@pytest.mark.slow
@pytest.mark.parametrize("kind", TRAJECTORY_KINDS)
@pytest.mark.parametrize("scene_args", [(0, "office", "medium"), (2, "bedroom", "large")])
def test_trajectories_stay_inside_outside_objects_and_look_at_something(kind, scene_args):
    s = _scene(*scene_args)
    poses = make_trajectory(s, kind, 120, seed=1)
    assert poses.shape == (120, 4, 4)
    R = poses[:, :3, :3]
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    p = poses[:, :3, 3]
    assert s.inside_rooms(p, margin=0.1).all()
    assert p[:, 2].min() >= 1.15 and p[:, 2].max() <= 1.75
    assert not _inside_any_hull(s, p, margin=0.05).any()
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert step.max() < 0.06  # < 1.8 m/s at 30 frames/s: smooth, hand-held
    turn = np.arccos(np.clip((np.einsum("nij,nij->n", R[1:], R[:-1]) - 1) / 2, -1, 1))
    assert np.degrees(turn).max() < 5.0
    d = center_depths(scene_raycaster(s), poses)
    assert ((d > 0.4) & (d < 4.5)).mean() >= 0.9


def test_trajectory_is_deterministic(office):
    assert np.array_equal(make_trajectory(office, "walk", 30, seed=4), make_trajectory(office, "walk", 30, seed=4))


def test_walk_goes_into_the_second_room():
    s = generate_scene(1, "office", "medium", second_room=True)
    poses = make_trajectory(s, "walk", 300, seed=0)
    r1 = s.rooms[1]
    inside_second = np.all((poses[:, :2, 3] >= r1.bounds_min[:2]) & (poses[:, :2, 3] <= r1.bounds_max[:2]), axis=1)
    assert inside_second.any()


# --------------------------------------------------------------------------------------------------
# ground truth
# --------------------------------------------------------------------------------------------------
def test_keys_follow_octomap_convention():
    pts = np.array([[0.0, -0.0001, 1.23456], [-3.2, 7.99999, 0.05]])
    res = 0.05
    expect = np.floor(pts.astype(np.float32).astype(np.float64) * (1.0 / res)).astype(int) + 32768
    assert np.array_equal(coords_to_keys(pts, res), expect)


@pytest.mark.slow
def test_backprojected_pixels_land_on_ground_truth_surfaces_of_their_class():
    s = generate_scene(0, "office", "small")
    res = 0.02
    gt = gt_voxels(s, res)
    assert len(gt) > 1000 and gt.keys.dtype == np.int32 and gt.class_ids.dtype == np.uint16
    r = Renderer(s, SMALL, noise=False)
    cam = r.intrinsics
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    hits, total = {}, {}
    for T in make_trajectory(s, "loop", 60, seed=0)[::12]:
        view = r.render(T)
        z = view.depth.astype(np.float64)
        m = z > 0
        pc = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], -1)[m]
        cls, _ = gt.lookup(coords_to_keys(pc @ T[:3, :3].T + T[:3, 3], res))
        lab = view.labels[m]
        for c in np.unique(lab):
            sel = lab == c
            hits[c] = hits.get(c, 0) + int((cls[sel] == c).sum())
            total[c] = total.get(c, 0) + int(sel.sum())
    assert sum(hits.values()) / sum(total.values()) >= 0.95
    for c in total:
        if total[c] >= 2000:
            assert hits[c] / total[c] >= 0.9, INDOOR_LABELS.names[c]


def test_gt_voxels_are_deterministic_and_floor_is_on_both_sides_of_z0():
    s = generate_scene(2, "bedroom", "small")
    a, b = gt_voxels(s, 0.1), gt_voxels(s, 0.1)
    assert np.array_equal(a.keys, b.keys) and np.array_equal(a.class_ids, b.class_ids)
    floor = a.keys[a.class_ids == INDOOR_LABELS.id_of("floor")]
    assert set(np.unique(floor[:, 2])) == {32767, 32768}


# --------------------------------------------------------------------------------------------------
# export
# --------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_export_is_byte_identical_and_reads_back_through_tum_dataset(tmp_path):
    from semmap.datasets import TumDataset

    calls = []
    kwargs = dict(scene_seed=2, kind="living_room", trajectory="orbit", frames=5, size="small",
                  intrinsics=SMALL)
    a = simulate_sequence(tmp_path / "a", progress=lambda i, n: calls.append((i, n)), **kwargs)
    b = simulate_sequence(tmp_path / "b", **kwargs)
    assert calls == [(i, 5) for i in range(1, 6)]
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert files_a == files_b
    for rel in files_a:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "camera.json", "labelset.json", "objects.json",
                 "scene.json"):
        assert (a / name).is_file(), name
    assert (a / "rgb" / "0.000000.png").is_file() and (a / "rgb" / "0.033333.png").is_file()

    scene = generate_scene(2, "living_room", "small")
    poses = make_trajectory(scene, "orbit", 5, seed=2)
    renderer = Renderer(scene, SMALL, noise=KinectNoise(seed=2))
    ds = TumDataset(a)
    frames = list(ds)
    assert len(frames) == 5
    assert ds.label_set.names == INDOOR_LABELS.names
    assert np.array_equal(ds.label_set.colors, INDOOR_LABELS.colors)
    for i, f in enumerate(frames):
        view = renderer.render(poses[i], frame_index=i)
        assert f.timestamp == pytest.approx(i / 30.0, abs=1e-6)
        assert np.allclose(f.T_world_cam, poses[i], atol=1e-6)
        assert np.array_equal(f.rgb, view.rgb)
        assert np.array_equal(f.labels, view.labels)
        assert np.array_equal(f.instances, view.instances)
        assert np.abs(f.depth - view.depth).max() <= 0.5 / 5000 + 1e-6
    objects = json.loads((a / "objects.json").read_text())
    assert [o["id"] for o in objects] == [o.instance_id for o in scene.objects]
    assert set(objects[0]) == {"id", "class", "class_id", "centroid", "bbox_min", "bbox_max"}
    info = json.loads((a / "scene.json").read_text())
    assert info["trajectory"] == "orbit" and info["frames"] == 5 and info["seed"] == 2
