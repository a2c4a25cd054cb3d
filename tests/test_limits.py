"""Issue 31, cases M1-M10 and H1-H5: every numeric option checked against one table of limits, memory estimated
and refused beyond the budget before it is allocated, and no wait without an end (all without allocating much)."""

from __future__ import annotations

import math
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from semmap import limits
from semmap.config import InputConfig, MappingConfig, OnlineConfig, OutputConfig, RunConfig, SemanticsConfig
from semmap.errors import ConfigError, SemmapError
from semmap.limits import MemoryBudgetError

SMALL = 64 << 20  # a 64 MB budget stands in for a machine's memory


@pytest.fixture
def small_budget(monkeypatch):
    """Available memory of 85 MB: the default budget (75 %) is 64 MB."""
    monkeypatch.delenv(limits.BUDGET_ENV, raising=False)
    monkeypatch.setattr(limits, "available_memory", lambda: int(SMALL / limits.DEFAULT_BUDGET_SHARE))
    limits.set_memory_budget(None)
    yield
    limits.set_memory_budget(None)


# ---------------------------------------------------------------------------------------------- one table
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, 0.0, 11.0, "x"])
def test_a_limit_refuses_nan_inf_and_out_of_range_in_one_line_naming_the_option(value) -> None:
    with pytest.raises(ConfigError, match=r"--resolution must be a (finite )?number"):
        limits.check("resolution", value)


def test_a_limit_passes_good_values_and_none() -> None:
    assert limits.check("resolution", 0.05) == 0.05
    assert limits.check("particles", None) is None
    with pytest.raises(ConfigError, match="whole number"):
        limits.check("particles", 2.5)


@pytest.mark.parametrize("section, field, value", [
    (MappingConfig, "resolution", math.nan), (MappingConfig, "resolution", 1e300),
    (MappingConfig, "prob_hit", math.nan),
    (MappingConfig, "max_range", math.inf), (MappingConfig, "min_depth", -1.0), (SemanticsConfig, "lam", math.nan),
    (SemanticsConfig, "max_confidence", 0.0), (SemanticsConfig, "batch_size", 100000),
    (SemanticsConfig, "input_size", (20000, 20000)), (SemanticsConfig, "input_size", 10),
    (OnlineConfig, "rate", math.nan),
    (InputConfig, "max_frames", 10**12),
])
def test_the_configuration_takes_its_bounds_from_the_table(section, field, value) -> None:
    kwargs = {"dataset": Path("x")} if section is InputConfig else {}
    with pytest.raises(ConfigError, match=rf"{section.section}\.{field}\)? must be "):  # semmap's line, not pydantic's
        section(**kwargs, **{field: value})


def test_config_bounds_are_the_tables() -> None:
    meta = {type(m).__name__: m for m in MappingConfig.model_fields["resolution"].metadata}
    assert meta["Ge"].ge == limits.LIMITS["resolution"].lo and meta["Le"].le == limits.LIMITS["resolution"].hi


def _run(args: list[str]):
    from semmap.cli import app

    return CliRunner().invoke(app, args)


def test_cli_run_refuses_a_nan_resolution_before_any_work(tmp_path: Path) -> None:
    result = _run(["run", str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--resolution", "nan"])
    assert isinstance(result.exception, SemmapError) and "resolution" in str(result.exception)
    assert not (tmp_path / "o").exists()


def test_m1_cli_run_refuses_a_huge_input_size(tmp_path: Path) -> None:
    result = _run(["run", str(tmp_path), "--out", str(tmp_path / "o"), "--segmenter", "fcn",
                   "--input-size", "20000x20000"])
    assert isinstance(result.exception, SemmapError) and "--input-size" in str(result.exception)


# ---------------------------------------------------------------------------------------------- the budget
def test_budget_sources_in_order(monkeypatch, small_budget) -> None:
    assert limits.memory_budget()[0] == pytest.approx(SMALL, abs=1)
    monkeypatch.setenv(limits.BUDGET_ENV, "2G")
    assert limits.memory_budget() == (2 << 30, limits.BUDGET_ENV)
    limits.set_memory_budget("512M")
    assert limits.memory_budget() == (512 << 20, "--memory-budget")


@pytest.mark.parametrize("text", ["", "abc", "-1G", "nan", "inf", "10", "1e400G"])
def test_a_bad_budget_is_one_line(text) -> None:
    with pytest.raises(ConfigError, match="--memory-budget"):
        limits.parse_size(text)


def test_available_memory_reads_meminfo() -> None:
    assert limits.available_memory() > 0


def test_m2_particles_beyond_the_limit_or_the_budget_are_refused(small_budget) -> None:
    from semmap.localization.filter import FilterSettings

    with pytest.raises(ConfigError, match="--particles"):
        FilterSettings(particles=100_000_000)
    FilterSettings(particles=1_000_000)  # within the table; its memory is checked where it is allocated
    with pytest.raises(MemoryBudgetError, match=r"--particles 1,000,000 needs about 256\.0 MB.*budget of 67\.1 MB"):
        limits.check_particles(1_000_000)
    limits.check_particles(2000)


def test_m2_the_filter_checks_before_allocating(small_budget) -> None:
    from semmap.localization.filter import FilterSettings, ParticleFilter

    with pytest.raises(MemoryBudgetError, match="--particles"):
        ParticleFilter(prior=None, settings=FilterSettings(particles=5_000_000))  # the prior is never touched


def test_m2_cli_localize_refuses_in_one_line(tmp_path: Path) -> None:
    result = _run(["localize", str(tmp_path / "map.semmap"), str(tmp_path), "--out", str(tmp_path / "o"),
                   "--particles", "100000000"])
    assert isinstance(result.exception, SemmapError) and "--particles" in str(result.exception)


def test_m1_network_input_budget(small_budget) -> None:
    from semmap.perception.network import NetworkInput, _check_input_budget

    with pytest.raises(MemoryBudgetError, match=r"--input-size 4096x4096 with a batch of 4"):
        _check_input_budget(NetworkInput(size=(4096, 4096)), 4)
    with pytest.raises(MemoryBudgetError):
        _check_input_budget(NetworkInput(short_side=4000), 1)
    _check_input_budget(NetworkInput(short_side=384), 4)


def test_m3_h1_a_fine_resolution_over_the_first_view_is_refused(small_budget) -> None:
    from semmap.maps.semantic_octomap import SemanticOctoMap
    from semmap.pipeline import Mapper

    view = np.array([[-2.0, -1.5, 0.5], [2.0, 1.5, 4.0]])
    with pytest.raises(MemoryBudgetError, match=r"--resolution 0\.002 over the first frame's view of 4\.0x3\.0x4\.0"):
        Mapper([SemanticOctoMap(0.002)], min_depth=0.1, max_depth=8.0)._check_extent(view, np.zeros(3))
    Mapper([SemanticOctoMap(0.05)], min_depth=0.1, max_depth=8.0)._check_extent(view, np.zeros(3))


def test_m6_m7_simulate_frames_and_image_size(small_budget, tmp_path: Path) -> None:
    from semmap.sim.export import simulate_sequence

    with pytest.raises(ConfigError, match="--frames must be"):
        simulate_sequence(tmp_path / "a", frames=100_000_000)
    with pytest.raises(ConfigError, match="--image-size must be"):
        simulate_sequence(tmp_path / "b", frames=1, image_size=(20000, 20000))
    with pytest.raises(MemoryBudgetError, match=r"--frames 1,000,000 needs about 1\.0 GB"):
        simulate_sequence(tmp_path / "c", frames=1_000_000)
    assert not any(tmp_path.iterdir())  # refused before the folder is made


def test_m7_cli_simulate_refuses_in_one_line(tmp_path: Path) -> None:
    result = _run(["simulate", "--out", str(tmp_path / "s"), "--frames", "100000000", "--memory-budget", "1G"])
    assert isinstance(result.exception, SemmapError) and "--frames" in str(result.exception)
    assert not (tmp_path / "s").exists()


def test_m8_m9_train_batch_and_input_size(small_budget, tmp_path: Path) -> None:
    from semmap.train.trainer import TrainSettings

    base = {"model": "fcn", "data": (tmp_path,), "out": tmp_path / "t"}
    with pytest.raises(ConfigError, match="--batch must be"):
        TrainSettings(**base, batch=100_000)
    with pytest.raises(MemoryBudgetError, match="--input-size 8000x6000 with a batch of 8"):
        TrainSettings(**base, input_size=(8000, 6000))
    for bad in ({"lr": math.nan}, {"epochs": math.inf}, {"depth_scale": 0.0}):
        with pytest.raises(ConfigError):
            TrainSettings(**base, **bad)
    TrainSettings(**base, batch=4)


# ---------------------------------------------------------------------------------------------- no hang
def _template(tmp_path: Path) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=tmp_path), output=OutputConfig(out=tmp_path / "o"))


@pytest.mark.parametrize("kwargs, match", [
    ({"workers": 0}, "--workers must be"),
    ({"workers": 2, "cpus_per_run": 64}, "needs 64 CPUs, the local cluster has 2"),
    ({"cpus_per_run": math.nan}, "--cpus-per-run must be"),
])
def test_h4_h5_batch_refuses_unschedulable_runs_before_ray_starts(tmp_path: Path, kwargs, match) -> None:
    from semmap.batch import run_batch

    with pytest.raises(ConfigError, match=match):
        run_batch(_template(tmp_path), [], **kwargs)


def test_h2_h3_a_full_or_read_only_folder_refuses_the_recording(tmp_path: Path, monkeypatch) -> None:
    from semmap.viz import rerun_log

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(rerun_log.shutil, "disk_usage", lambda _: usage(2 << 20, 2 << 20, 4096))
    with pytest.raises(ConfigError, match=r"only 0\.0 MB free"):
        rerun_log.check_recording_space(tmp_path / "x.rrd")
    monkeypatch.setattr(rerun_log.os, "access", lambda *_: False)
    with pytest.raises(ConfigError, match="is not writable"):
        rerun_log.check_recording_space(tmp_path / "x.rrd")


def test_m4_a_prior_grid_beyond_the_budget_is_refused_before_it_is_built(small_budget) -> None:
    from semmap.localization.prior import build_prior

    corners = np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 3.0]])
    with pytest.raises(MemoryBudgetError, match=r"the prior map's lookup grid of .* cells of 0.01 m"):
        build_prior(corners, 0.01)
    assert build_prior(corners, 0.25).num_occupied == 2
