"""The one map interface: every map kind integrates an Observation, reads back as a MapCloud, saves and
describes itself; the pipeline builds maps only through the registry."""

from __future__ import annotations

import numpy as np
import pytest

from semmap.config import InputConfig, OutputConfig, RunConfig
from semmap.errors import ConfigError
from semmap.factories import get_map
from semmap.io.map_files import MAP_FILES, load_map, native_file, save_map_files
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MapKind, map_kind
from semmap.types import EMPTY_LABEL, LabelSet, Observation, TopKProbs


def wall_observation(n: int = 400, *, label: int = 2, seed: int = 0) -> Observation:
    """A noisy wall at x = 2 m seen from the origin, every point of class ``label`` with confidence 0.7."""
    rng = np.random.default_rng(seed)
    pts = np.column_stack([np.full(n, 2.0), rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n)])
    labels = np.full((n, 3), EMPTY_LABEL, np.uint16)
    labels[:, 0] = label
    probs = np.zeros((n, 3), np.float32)
    probs[:, 0] = 0.7
    return Observation(pts.astype(np.float32), np.zeros(3), rng.integers(0, 200, (n, 3), dtype=np.uint8),
                       TopKProbs(labels, probs))


def config(tmp_path) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=tmp_path), output=OutputConfig(out=tmp_path / "out"))


@pytest.mark.parametrize("kind", list(MapKind))
def test_every_map_kind_integrates_reads_back_saves_and_describes_itself(kind, tmp_path):
    m = get_map(kind, config(tmp_path), LabelSet.generic(4))
    assert isinstance(m, SemanticMap) and m.kind == kind
    ms = m.integrate(wall_observation())
    assert ms and all(v >= 0 for v in ms.values())
    cloud = m.cloud()
    assert len(cloud) > 0 and cloud.centers.shape == (len(cloud), 3) and cloud.colors.dtype == np.uint8
    assert np.all(np.abs(cloud.centers[:, 0] - 2.0) <= max(cloud.resolution, 0.05))
    assert np.all(cloud.labels == 2) and np.all((cloud.confidence > 0.5) & (cloud.confidence <= 1.0))
    sizes = save_map_files(m, tmp_path / "out")
    assert list(sizes) == list(MAP_FILES[kind])
    assert all((tmp_path / "out" / name).stat().st_size == size for name, size in sizes.items())
    back = load_map(tmp_path / "out" / native_file(kind))
    assert back.kind == kind and np.array_equal(back.cloud().labels, cloud.labels)
    d = m.describe()
    assert d["bytes_in_memory"] > 0 and d["bytes_per_voxel_in_memory"] > 0


def test_observation_rejects_arrays_that_do_not_match_its_points():
    obs = wall_observation(10)
    with pytest.raises(ConfigError, match="colours"):
        Observation(obs.points_world, obs.origin, obs.colors[:5])
    with pytest.raises(ConfigError, match="class sets"):
        Observation(obs.points_world, obs.origin, obs.colors, TopKProbs(obs.semantics.labels[:3],
                                                                        obs.semantics.probs[:3]))


def test_unknown_map_names_are_a_clear_error():
    assert map_kind("octomap") == MapKind.OCTOMAP
    with pytest.raises(ConfigError, match="octomap"):
        map_kind("octree")
