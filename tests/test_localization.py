"""Semantic Monte-Carlo localization: kernels against slow references, the filter's parts, runs in simulated rooms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import naive
from helpers import run_cli
from semmap.datasets.simulated import SimulatedDataset
from semmap.errors import ConfigError
from semmap.keys import keys_to_coords
from semmap.labels import INDOOR_LABELS
from semmap.localization import _kernels as kern
from semmap.localization.filter import FilterSettings, ParticleFilter, tempering
from semmap.localization.motion import GroundTilt, MotionMode, NoisyGroundTruth, heading
from semmap.localization.observation import (
    LikelihoodParams,
    ObservationKind,
    Scan,
    likelihood_tables,
    make_scan,
    score,
)
from semmap.localization.prior import build_prior, dense_class_probs
from semmap.localization.run import InitMode, localize
from semmap.sim.ground_truth import gt_voxels
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import DEFAULT_INTRINSICS, EMPTY_LABEL, LabelSet, TopKProbs, invert_pose, make_pose, pose_change

RES = 0.05
CAMERA = DEFAULT_INTRINSICS.scaled(0.25)  # 160 x 120


# ---------------------------------------------------------------------------------------------- small synthetic maps
def random_prior(rng: np.random.Generator, n_classes: int = 6, n_vox: int = 300):
    """A prior over random occupied voxels in a 1 m box, with random top-2 class sets."""
    keys = np.unique(rng.integers(0, 20, (n_vox, 3)), axis=0)
    centers = (keys + 0.5) * RES
    labels = np.full((len(keys), 2), EMPTY_LABEL, np.uint16)
    labels[:, 0] = rng.integers(1, n_classes, len(keys))
    labels[:, 1] = np.where(rng.random(len(keys)) < 0.5, (labels[:, 0] % (n_classes - 1)) + 1, EMPTY_LABEL)
    probs = np.where(labels != EMPTY_LABEL, np.array([0.6, 0.25], np.float32), 0.0).astype(np.float32)
    free = (np.stack(np.meshgrid(*[np.arange(20)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) * RES
    return build_prior(centers, RES, free_centers=free, labels=labels, probs=probs,
                       label_set=LabelSet.generic(n_classes), cutoff=0.3, clearance=0.0)


def random_scan(rng: np.random.Generator, n_classes: int = 6, n: int = 40) -> Scan:
    labels = np.full((n, 3), EMPTY_LABEL, np.uint16)
    labels[:, 0] = rng.integers(0, n_classes, n)
    labels[:, 1] = (labels[:, 0] + rng.integers(1, n_classes - 1, n)) % n_classes  # a set holds a class once
    probs = np.stack([rng.uniform(0.4, 0.7, n), rng.uniform(0.0, 0.2, n), np.zeros(n)], 1).astype(np.float32)
    others = (1.0 - probs.sum(axis=1)).astype(np.float32)
    others[: n // 5] = -1.0  # some points without classes
    return Scan(rng.uniform(-0.6, 0.6, (n, 3)).astype(np.float32), labels, probs, others,
                rng.integers(0, n_classes, n).astype(np.uint16))


def random_poses(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    R = Rotation.random(n, random_state=int(rng.integers(1 << 31))).as_matrix()
    t = rng.uniform(0.2, 0.8, (n, 3))
    return np.ascontiguousarray(R), t


def test_likelihood_kernel_matches_the_slow_reference():
    rng = np.random.default_rng(0)
    prior = random_prior(rng)
    scan = random_scan(rng)
    R, t = random_poses(rng, 12)
    params = LikelihoodParams(sigma=0.05)
    tables = likelihood_tables(params, prior.num_classes - 1)
    for kind, semantic in ((ObservationKind.SEMANTIC, True), (ObservationKind.GEOMETRY, False)):
        out = np.zeros(len(R))
        score(kind, prior, R, t, scan, params, out)
        ref = naive.likelihood_scores(R, t, scan.points, scan.labels, scan.probs, scan.others, prior, tables,
                                      semantic, params.semantic_floor, math.log(params.z_rand))
        np.testing.assert_allclose(out, ref * params.effective_points / len(scan), rtol=1e-6, atol=1e-6)


def test_likelihood_tables_follow_the_mixture_formula():
    params = LikelihoodParams(sigma=0.04, z_hit=0.7, z_rand=0.1, semantic_floor=0.3)
    tab = likelihood_tables(params, 29)
    for d in (0.0, 0.01, 0.03, 0.07, 0.12):
        qd = min(int(d * d * tab.d2_scale + 0.5), len(tab.geo) - 1)
        g = math.exp(-d * d / (2 * params.sigma**2))
        assert tab.geo[qd] == pytest.approx(math.log(params.z_hit * g + params.z_rand), abs=2e-3)
        for f in (0.3, 1.0, 7.5):
            x = tab.gauss[qd] * f
            got = tab.log_mix[min(int(x * tab.x_scale + 0.5), len(tab.log_mix) - 1)]
            assert got == pytest.approx(math.log(params.z_hit * g * f + params.z_rand), abs=0.02)
    far = math.log(params.z_rand)
    assert tab.geo[-1] == pytest.approx(far) and tab.gauss[-1] == 0.0 and tab.log_mix[0] == pytest.approx(far)


def test_cosine_kernel_matches_the_slow_reference():
    rng = np.random.default_rng(1)
    prior = random_prior(rng)
    scan = random_scan(rng)
    R, t = random_poses(rng, 10)
    out = np.zeros(len(R))
    score(ObservationKind.COSINE, prior, R, t, scan, LikelihoodParams(), out)
    ref = naive.cosine_scores(R, t, scan.points, scan.local_labels, prior)
    np.testing.assert_allclose(out, np.log(np.maximum(ref, 1e-6)), rtol=1e-9, atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-0.5, 0.5), min_size=6, max_size=6), st.lists(st.floats(-0.3, 0.3), min_size=6, max_size=6))
def test_motion_kernel_composes_pose_motion_and_noise(u6, noise6):
    rng = np.random.default_rng(2)
    R, t = random_poses(rng, 3)
    u = make_pose(Rotation.from_rotvec(u6[3:]).as_matrix(), u6[:3])
    noise = np.tile(np.asarray(noise6, np.float64), (3, 1))
    R2, t2 = R.copy(), t.copy()
    kern.propagate_6dof(R2, t2, np.ascontiguousarray(u[:3, :3]), np.ascontiguousarray(u[:3, 3]), noise)
    E = make_pose(Rotation.from_rotvec(noise6[3:]).as_matrix(), noise6[:3])
    for i in range(3):
        expect = make_pose(R[i], t[i]) @ u @ E
        np.testing.assert_allclose(R2[i], expect[:3, :3], atol=1e-9)
        np.testing.assert_allclose(t2[i], expect[:3, 3], atol=1e-9)


def test_nearest_grid_names_the_nearest_occupied_voxel_within_the_cutoff():
    rng = np.random.default_rng(3)
    prior = random_prior(rng)
    cells = rng.integers(0, prior.nearest.size, 400)
    centers = prior.cell_centers(cells)
    d = np.linalg.norm(centers[:, None, :] - prior.centers[None].astype(np.float64), axis=2)
    best = d.min(axis=1)
    got = prior.nearest[cells]
    inside = best < prior.cutoff - 1e-4
    assert (got[best > prior.cutoff + 1e-4] == -1).all()
    np.testing.assert_allclose(d[np.flatnonzero(inside), got[inside]], best[inside], atol=1e-6)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_dense_class_distributions_keep_the_set_and_sum_to_one(seed):
    rng = np.random.default_rng(seed)
    k, C = 3, 8
    labels = np.full((5, k), EMPTY_LABEL, np.uint16)
    probs = np.zeros((5, k), np.float32)
    for r in range(4):  # row 4 stays empty
        m = int(rng.integers(1, k + 1))
        labels[r, :m] = rng.choice(np.arange(1, C), m, replace=False)
        p = rng.dirichlet(np.ones(m + 1))[:m]
        probs[r, :m] = np.sort(p)[::-1]
    dense = dense_class_probs(labels, probs, C)
    np.testing.assert_allclose(dense.sum(axis=1), 1.0, atol=1e-5)
    assert (dense[:, 0] == 0).all()
    for r in range(4):
        for lab, p in zip(labels[r], probs[r], strict=True):
            if lab != EMPTY_LABEL:
                assert dense[r, lab] == pytest.approx(p, abs=1e-6)
    np.testing.assert_allclose(dense[4, 1:], 1.0 / (C - 1), atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(1.0, 400.0))
def test_tempering_never_shrinks_the_effective_sample_size_below_the_floor(seed, sharpness):
    rng = np.random.default_rng(seed)
    logw = rng.normal(0, 0.3, 500)
    scores = -sharpness * rng.random(500)
    beta = tempering(logw, scores, 50.0)
    w = np.exp(logw + beta * scores - (logw + beta * scores).max())
    ess = w.sum() ** 2 / np.sum(w * w)
    assert 0.0 < beta <= 1.0
    assert ess >= min(50.0, 500.0) * 0.999 or beta <= 2.0**-12


def test_low_variance_resampling_copies_particles_in_proportion_to_their_weight():
    rng = np.random.default_rng(4)
    prior = random_prior(rng)
    pf = ParticleFilter(prior, FilterSettings(particles=1000), seed=0)
    pf.init_global()
    pf.t[:, 0] = np.arange(1000) // 250  # four groups of 250
    w = np.where(pf.t[:, 0] == 3, 7.0, 1.0)
    pf._resample(w / w.sum())
    counts = np.bincount(pf.t[:, 0].astype(int), minlength=4)
    np.testing.assert_array_equal(counts, [100, 100, 100, 700])


def test_global_samples_lie_in_free_space_with_clearance():
    rng = np.random.default_rng(5)
    prior = random_prior(rng)
    pf = ParticleFilter(prior, FilterSettings(particles=500), seed=1)
    pf.init_global()
    cells = prior.cell_index(pf.t)
    assert (cells >= 0).all() and prior.free_clear[cells].all()


# ---------------------------------------------------------------------------------------------- simulated rooms
def ground_truth_prior(scene):
    """Lookup grids of a scene's true surface voxels (labelled 0.9) and its free room interior."""
    gt = gt_voxels(scene, RES)
    centers = keys_to_coords(gt.keys, RES)
    lo, hi = scene.bounds_min, scene.bounds_max
    axes = [np.arange(lo[i] + RES / 2, hi[i], RES) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    labels = np.full((len(centers), 1), EMPTY_LABEL, np.uint16)
    labels[:, 0] = gt.class_ids
    probs = np.full((len(centers), 1), 0.9, np.float32)
    return build_prior(centers, RES, free_centers=grid, labels=labels, probs=probs, label_set=INDOOR_LABELS)


def labelled_frames(scene, poses, seed=0):
    """Frames with class sets from their true labels (0.8 on the true class)."""
    frames = SimulatedDataset(scene, poses, intrinsics=CAMERA, seed=seed)
    return [f.with_(semantics=TopKProbs.from_hard_labels(f.labels, 0.8, len(INDOOR_LABELS))) for f in frames]


@pytest.fixture(scope="module")
def office():
    scene = generate_scene(0, "office", "small")
    poses = make_trajectory(scene, "loop", 120, seed=1)[::3]
    return scene, ground_truth_prior(scene), labelled_frames(scene, poses)


def _run(prior, frames, *, init, mode=MotionMode.SIX_DOF, model=ObservationKind.SEMANTIC, particles=1000, seed=0,
         init_pose=None):
    settings_ = FilterSettings(particles=particles, mode=mode, model=model)
    return localize(prior, frames, NoisyGroundTruth(0.05, 0.05, seed=seed), settings=settings_, init=init,
                    init_pose=init_pose, segment=lambda f: f.semantics,
                    tilt_of=lambda f: GroundTilt.from_pose(f.T_world_cam), seed=seed, points=300)


@pytest.mark.slow
def test_tracking_follows_the_camera_to_a_few_centimetres(office):
    _, prior, frames = office
    s = _run(prior, frames, init=InitMode.TRACKING, particles=500).summary()
    assert s["converged_at_end"] and s["converged_to_truth"]
    assert s["pos_err_m_after_convergence"]["median"] < 0.05
    assert s["rot_err_deg_after_convergence"]["median"] < 2.0


def test_global_initialisation_finds_the_camera_in_the_room(office):
    _, prior, frames = office
    result = _run(prior, frames, init=InitMode.GLOBAL, mode=MotionMode.GROUND, particles=2000)
    s = result.summary()
    assert s["frames_to_converge"] is not None and s["frames_to_converge"] <= 20
    assert s["converged_to_truth"] and s["pos_err_m_after_convergence"]["median"] < 0.05
    assert not result.updates[0].estimate.converged  # a spread-out set is not "converged"


class _HiddenJump:
    """Ground-truth motion that hides the camera being carried elsewhere after frame ``at`` (a kidnapping)."""

    name = "gt-with-a-hidden-jump"

    def __init__(self, frames, at: int) -> None:
        self._offset = frames[at - 1].T_world_cam @ invert_pose(frames[at].T_world_cam)
        self._first_after = frames[at].index

    def pose(self, frame):
        return frame.T_world_cam if frame.index < self._first_after else self._offset @ frame.T_world_cam


def test_a_kidnapped_filter_recovers_by_injecting_particles(office):
    _, prior, frames = office
    seq = frames[:10] + frames[22:]  # carried 12 frames ahead along the loop without the motion showing it
    settings_ = FilterSettings(particles=1000, mode=MotionMode.GROUND)
    result = localize(prior, seq, _HiddenJump(seq, 10), settings=settings_, init=InitMode.TRACKING,
                      segment=lambda f: f.semantics, tilt_of=lambda f: GroundTilt.from_pose(f.T_world_cam),
                      points=300)
    errors = [u.pos_err_m for u in result.updates]
    assert max(errors[:10]) < 0.05 and errors[10] > 0.5
    assert sum(u.estimate.injected for u in result.updates[10:]) > 0
    assert max(errors[-3:]) < 0.05


def test_semantics_tell_a_symmetric_room_from_its_turned_twin():
    scene = generate_scene(0, "office", "small", symmetric=True)
    prior = ground_truth_prior(scene)
    room = scene.rooms[0]
    turn = np.diag([-1.0, -1.0, 1.0, 1.0])
    turn[:2, 3] = (room.bounds_min + room.bounds_max)[:2]
    poses = make_trajectory(scene, "loop", 60, seed=2)[::10]
    frames = labelled_frames(scene, poses)
    rng = np.random.default_rng(0)
    gaps = {}
    for kind in (ObservationKind.GEOMETRY, ObservationKind.SEMANTIC):
        diffs = []
        for f in frames:
            scan = make_scan(f.depth, f.intrinsics, f.semantics, resolution=RES, max_points=300, rng=rng,
                             num_classes=len(INDOOR_LABELS))
            T = np.stack([f.T_world_cam, turn @ f.T_world_cam])
            out = np.zeros(2)
            score(kind, prior, np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3]), scan,
                  LikelihoodParams(), out)
            diffs.append(out[0] - out[1])
        gaps[kind] = np.array(diffs)
    geometry, semantic = gaps[ObservationKind.GEOMETRY].sum(), gaps[ObservationKind.SEMANTIC].sum()
    assert abs(geometry) < 10.0  # over the frames the geometry barely tells the poses apart (voxel lattice) ...
    assert semantic > 50.0 and semantic > 5 * abs(geometry)  # ... the classes do


def test_symmetric_scene_twin_views_see_the_same_depth_and_other_classes():
    scene = generate_scene(1, "bedroom", "medium", symmetric=True)
    assert scene.params["symmetric"] and len(scene.rooms) == 1
    room = scene.rooms[0]
    turn = np.diag([-1.0, -1.0, 1.0, 1.0])
    turn[:2, 3] = (room.bounds_min + room.bounds_max)[:2]
    pose = make_trajectory(scene, "loop", 30, seed=0)[15]
    a, b = (next(iter(SimulatedDataset(scene, T[None], intrinsics=CAMERA, noise=False))) for T in (pose, turn @ pose))
    np.testing.assert_allclose(a.depth, b.depth, atol=1e-3)
    assert (a.labels != b.labels).mean() > 0.05
    with pytest.raises(Exception, match="one room"):
        generate_scene(1, "bedroom", "medium", second_room=True, symmetric=True)


def test_ground_mode_needs_the_camera_height_and_tilt(office):
    _, prior, frames = office
    pf = ParticleFilter(prior, FilterSettings(particles=10, mode=MotionMode.GROUND))
    with pytest.raises(ConfigError, match="height"):
        pf.init_global()
    tilt = GroundTilt.from_pose(frames[0].T_world_cam)
    pf.init_tracking(frames[0].T_world_cam, tilt)
    np.testing.assert_allclose(pf.t[:, 2], frames[0].T_world_cam[2, 3])
    T0 = frames[0].T_world_cam
    assert pose_change(tilt.pose(T0[0, 3], T0[1, 3], float(heading(T0[:3, :3]))), T0)[1] < 1e-6
    u = invert_pose(frames[0].T_world_cam) @ frames[1].T_world_cam
    with pytest.raises(ConfigError, match="height"):
        pf.predict(u, None)


# ---------------------------------------------------------------------------------------------- command line
@pytest.fixture(scope="module")
def small_office_map(tmp_path_factory, office):
    """map.semmap of the small office built from the fixture's frames, and a simulated sequence of the same scene."""
    from semmap.geometry import backproject_world
    from semmap.io.map_files import save_map_files
    from semmap.io.native import save_map
    from semmap.maps.semantic_octomap import SemanticOctoMap
    from semmap.maps.voxel_grid import SemanticVoxelGrid
    from semmap.sim.export import simulate_sequence
    from semmap.types import Observation

    _, _, frames = office
    root = tmp_path_factory.mktemp("loc")
    m = SemanticOctoMap(RES, label_set=INDOOR_LABELS)
    for f in frames:
        pts, pix = backproject_world(f.depth, f.intrinsics, f.T_world_cam)
        flat = f.semantics.reshape_flat()
        m.insert_points(pts, f.T_world_cam[:3, 3], semantics=TopKProbs(flat.labels[pix], flat.probs[pix]))
    save_map(root / "map.semmap", m)
    grid = SemanticVoxelGrid(RES, label_set=INDOOR_LABELS)
    for f in frames:
        pts, pix = backproject_world(f.depth, f.intrinsics, f.T_world_cam)
        flat = f.semantics.reshape_flat()
        grid.integrate(Observation(pts, f.T_world_cam[:3, 3], np.zeros((len(pts), 3), np.uint8),
                                   TopKProbs(flat.labels[pix], flat.probs[pix])))
    save_map_files(grid, root)
    seq = simulate_sequence(root / "seq", scene_seed=0, kind="office", size="small", frames=24, trajectory_seed=1,
                            intrinsics=CAMERA)
    return root / "map.semmap", seq


@pytest.mark.slow
def test_localize_command_writes_the_trajectory_report_and_pictures(small_office_map, tmp_path):
    from semmap.io.trajectory import read_trajectory

    map_path, seq = small_office_map
    out = tmp_path / "out"
    r = run_cli("localize", str(map_path), str(seq), "--out", str(out), "--init", "tracking", "--motion", "gt-noisy",
                "--particles", "300", "--stride", "2", "--gif")
    assert r.returncode == 0, r.stderr
    for name in ("localization.txt", "localization.npz", "report.json", "report.md", "particles.png", "errors.png",
                 "particles.gif"):
        assert (out / name).stat().st_size > 0, name
    report = __import__("json").loads((out / "report.json").read_text())
    s = report["summary"]
    assert s["updates"] == 12 and s["model"] == "semantic" and s["particles"] == 300
    assert s["converged_at_end"] and s["pos_err_m_final"] < 0.1
    assert len(report["updates"]) == 12 and {"pos_err_m", "spread_m", "ms"} <= set(report["updates"][0])
    traj = read_trajectory(out / "localization.txt")
    assert len(traj) == 12
    npz = np.load(out / "localization.npz")
    assert npz["covariances"].shape == (12, 6, 6)
    assert "Converged after" in (out / "report.md").read_text()


@pytest.mark.slow
def test_localize_command_reports_bad_input_in_one_line(small_office_map, tmp_path):
    from semmap.localization.sequence import LocalizeOptions, localize_sequence

    map_path, seq = small_office_map
    r = run_cli("localize", str(tmp_path / "missing.semmap"), str(seq), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and r.stderr.strip().startswith("semmap: error:") and "missing.semmap" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    with pytest.raises(ConfigError, match="class sets"):
        localize_sequence(map_path, seq, tmp_path / "o", LocalizeOptions(segmenter="none"))
    with pytest.raises(ConfigError, match="neither"):
        localize_sequence(map_path, seq, tmp_path / "o", LocalizeOptions(motion="no-such-source"))


def test_a_voxel_grid_map_localizes_like_the_octree(small_office_map, office):
    from semmap.localization.prior import load_prior

    scene, _, frames = office
    map_path, _ = small_office_map
    octree, grid = load_prior(map_path), load_prior(map_path.parent / "voxelgrid.semmap")
    assert grid.num_classes == octree.num_classes == len(INDOOR_LABELS)
    assert abs(grid.num_occupied - octree.num_occupied) < 0.2 * octree.num_occupied
    # without free-space cells, global samples come from empty cells above a mapped floor, inside the room
    pf = ParticleFilter(grid, FilterSettings(particles=500), seed=0)
    pf.init_global()
    assert scene.inside_rooms(pf.t).mean() > 0.95
    s = _run(grid, frames[:15], init=InitMode.TRACKING, particles=300).summary()
    assert s["converged_to_truth"] and s["pos_err_m_after_convergence"]["median"] < 0.05
