"""``semmap run SEQ --continue PRIOR``: incompatible priors refused in one line before any work, a recording
localized in a prior and mapped into its frame with the prior's evidence kept, and the alignment's accuracy."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig, SemanticSource
from semmap.datasets.simulated import SimulatedDataset
from semmap.errors import ConfigError, SemmapError
from semmap.fusion.rules import FusionParams, FusionRule
from semmap.io.map_files import save_map
from semmap.labels import INDOOR_LABELS
from semmap.maps.registry import MapKind
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.runner import run_config
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import DEFAULT_INTRINSICS, LabelSet, invert_pose, pose_change

RES = 0.1
INTR = DEFAULT_INTRINSICS.scaled(0.25)  # 160 x 120: fast to render, enough for a scan


class _Recording(SimulatedDataset):
    """A simulated recording whose poses are given in its first camera's frame (as a tracker gives them)."""

    def __init__(self, *args, T_new_world: np.ndarray, **kw) -> None:
        super().__init__(*args, **kw)
        self.T_new_world = T_new_world

    def __iter__(self):
        for f in super().__iter__():
            yield replace(f, T_world_cam=self.T_new_world @ f.T_world_cam)


def _config(out: Path, *, resolution: float = RES, maps=(MapKind.OCTOMAP,), fusion: str | None = None) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=Path("sim")), mapping=MappingConfig(resolution=resolution, maps=maps),
                     semantics=SemanticsConfig(source=SemanticSource.LABELS, fusion=fusion),
                     output=OutputConfig(out=out, preview=False, plots=False))


def _empty_prior(folder: Path, *, resolution: float = RES, label_set: LabelSet = INDOOR_LABELS,
                 fusion: FusionParams | None = None) -> Path:
    folder.mkdir()
    save_map(folder / "map.semmap", SemanticOctoMap(resolution, label_set=label_set, fusion=fusion or FusionParams()))
    return folder


@pytest.fixture(scope="module")
def scene():
    return generate_scene(0, "office", "small")


def _tiny(scene, seed: int, frames: int, *, relative: bool) -> tuple[SimulatedDataset, np.ndarray]:
    poses = make_trajectory(scene, "walk", frames * 3, seed=seed)[::3]
    T = invert_pose(poses[0]) if relative else np.eye(4)
    return _Recording(scene, poses, seed=seed, intrinsics=INTR, name=f"rec{seed}", T_new_world=T), poses[0]


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"resolution": 0.05}, "resolution is 0.05, this run's 0.1"),
    ({"fusion": FusionParams(FusionRule.BAYES)}, "fusion rule is bayes, this run's topk"),
])
def test_an_incompatible_prior_is_refused_in_one_line_naming_the_file(tmp_path, kwargs, words):
    prior = _empty_prior(tmp_path / "prior", **kwargs)
    with pytest.raises(ConfigError) as err:
        run_config(_config(tmp_path / "out"), dataset=None, continue_from=prior)
    msg = str(err.value)
    assert words in msg and str(prior / "map.semmap") in msg and "\n" not in msg
    assert not (tmp_path / "out").exists()


def test_a_prior_without_the_runs_map_kind_or_of_another_label_set_is_refused(tmp_path, scene):
    prior = _empty_prior(tmp_path / "prior")
    with pytest.raises(ConfigError, match=r"no voxelgrid\.semmap \(voxelgrid\)"):
        run_config(_config(tmp_path / "out", maps=(MapKind.OCTOMAP, MapKind.VOXELGRID)), continue_from=prior)
    with pytest.raises(ConfigError, match="one map file, but this run builds octomap, voxelgrid"):
        run_config(_config(tmp_path / "out", maps=(MapKind.OCTOMAP, MapKind.VOXELGRID)),
                   continue_from=prior / "map.semmap")
    other = _empty_prior(tmp_path / "other", label_set=LabelSet.generic(5))
    rec, _ = _tiny(scene, 1, 2, relative=False)
    with pytest.raises(ConfigError, match=r"other/map\.semmap: the prior map's label set is 5 classes .* 30 classes"):
        run_config(_config(tmp_path / "out"), dataset=rec, continue_from=other)
    assert not (tmp_path / "out").exists()


def test_the_output_may_not_be_the_prior(tmp_path):
    prior = _empty_prior(tmp_path / "prior")
    with pytest.raises(SemmapError, match="is the input --continue"):
        run_config(_config(prior), continue_from=prior)


@pytest.fixture(scope="module")
def prior_run(tmp_path_factory, scene):
    """A finished run of one recording: the OctoMap at 10 cm and the fine point map (the alignment's surface)."""
    out = tmp_path_factory.mktemp("continue") / "prior"
    poses = make_trajectory(scene, "loop", 300, seed=0)[::15]  # 20 frames around the room
    first = SimulatedDataset(scene, poses, seed=0, intrinsics=INTR, name="prior")
    return run_config(_config(out, maps=(MapKind.OCTOMAP, MapKind.POINTS)), dataset=first)


@pytest.mark.slow
def test_a_continued_run_localizes_the_recording_and_keeps_the_priors_evidence(tmp_path, scene, prior_run):
    rec, T0 = _tiny(scene, 2, 12, relative=True)
    cont = run_config(_config(tmp_path / "cont"), dataset=rec, continue_from=prior_run.out_dir)
    c = cont.report["continued"]
    dt, dr = pose_change(T0, np.array(c["T_prior_seq"]))
    assert dt < 0.02 and dr < 1.0, (dt, dr)
    assert c["icp_surface"] == "point map" and c["converged_after_frames"] <= c["frames_localized"] <= 12
    # the prior's occupied cells are still there, and the new recording's frames added to them
    prior = prior_run.octomap
    before, after = prior.cells(), cont.octomap.cells()
    kept = np.isin(before.packed[prior.is_occupied(before.logodds)], after.packed)
    assert kept.all() and len(after.packed) > len(before.packed)
    md = (tmp_path / "cont" / "report.md").read_text()
    assert "## Continued from a prior map" in md and "converged after" in md


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 4])
def test_a_recording_starting_elsewhere_is_aligned_within_2_cm_and_1_degree(scene, prior_run, seed):
    from semmap.localization.align import align_recording
    from semmap.localization.prior import prior_from_octomap
    from semmap.pipeline import semantics_for

    rec, T0 = _tiny(scene, seed, 12, relative=True)
    surface = prior_run.map_of(MapKind.POINTS).cloud().centers
    a = align_recording(prior_from_octomap(prior_run.octomap), ((f, f.T_world_cam) for f in rec), surface=surface,
                        segment=lambda f: semantics_for(f, SemanticSource.LABELS, label_set=INDOOR_LABELS,
                                                        label_confidence=0.9, k=3), seed=seed)
    dt, dr = pose_change(T0, a.T_prior_seq)
    assert dt < 0.02 and dr < 1.0, (dt, dr, a.report())


def test_the_cli_refuses_an_incompatible_prior_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from semmap.cli import app

    prior = _empty_prior(tmp_path / "prior", resolution=0.2)
    r = CliRunner().invoke(app, ["run", str(tmp_path / "seq"), "--out", str(tmp_path / "out"), "--continue",
                                 str(prior), "--resolution", "0.1"])
    msg = str(r.exception)  # (semmap's entry point prints it as one "semmap: error: ..." line)
    assert r.exit_code != 0 and isinstance(r.exception, SemmapError), r.output
    assert msg.startswith("--continue") and "resolution is 0.2" in msg and "\n" not in msg
    assert not (tmp_path / "out").exists()
