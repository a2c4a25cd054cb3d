"""Checkpoints with a schema: every map saves and restores its state by stable public names (so renaming a private
attribute cannot break a resume), a restored map continues exactly like the map it came from, and a checkpoint of
another schema version or configuration is named in one line and the run starts over."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from helpers import make_room_frames, room_label_set
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
from semmap.errors import FormatError
from semmap.factories import get_map
from semmap.fusion.rules import FusionRule
from semmap.io.map_files import save_map_files
from semmap.io.staged_run import staging_folder
from semmap.io.state import VERSION, read_checkpoint, write_checkpoint
from semmap.io.tum_writer import write_tum_sequence
from semmap.maps.registry import MapKind
from semmap.pipeline import Pipeline
from semmap.types import LabelSet
from test_map_interface import wall_observation

#: Arrays a map may hold that a checkpoint does not keep: scratch reused between scans, and its fusion settings
#: (rebuilt from the configuration).
NOT_STATE = {"_grid", "_scratch", "_keys_buf", "_params"}


def _config(tmp_path, **semantics) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=tmp_path), mapping=MappingConfig(free_space=True),
                     semantics=SemanticsConfig(**semantics), output=OutputConfig(out=tmp_path / "out"))


def _arrays_held(obj, prefix: str = "") -> set[str]:
    """Attribute paths of every numpy array an object (and the maps and tables inside it) holds."""
    found = set()
    for name, value in vars(obj).items():
        if name in NOT_STATE:
            continue
        if isinstance(value, np.ndarray):
            found.add(prefix + name)
        elif hasattr(value, "__dict__") and type(value).__module__.startswith("semmap.maps"):
            found |= _arrays_held(value, f"{prefix}{name}.")
    return found


@pytest.mark.parametrize("kind", list(MapKind))
def test_a_maps_checkpoint_state_covers_every_array_it_holds(kind, tmp_path):
    """A new array attribute that the checkpoint schema does not name fails here, not in a user's resume."""
    m = get_map(kind, _config(tmp_path), LabelSet.generic(4))
    m.integrate(wall_observation())
    held = {path.rsplit(".", 1)[-1] for path in _arrays_held(m)}
    schema = set()
    for part in (m, getattr(m, "grid", None), getattr(m, "geometry", None)):
        schema |= set(getattr(part, "STATE_ARRAYS", {}).values())
    table = {"keys", "logodds", "attr", "counts"}  # the grids' hash table, saved as table_* by SemanticGrid.state
    assert held - schema - table == set()


@pytest.mark.parametrize("kind", list(MapKind))
@pytest.mark.parametrize("rule", [FusionRule.TOPK, FusionRule.BAYES])
def test_a_restored_map_continues_exactly_like_the_one_it_came_from(kind, rule, tmp_path):
    cfg = _config(tmp_path, fusion=rule)
    a = get_map(kind, cfg, LabelSet.generic(4))
    for seed in range(2):
        a.integrate(wall_observation(seed=seed))
    b = get_map(kind, cfg, LabelSet.generic(4))
    b.restore({name: np.array(v) for name, v in a.state().items()})  # copies, as read back from a file
    for m in (a, b):
        m.integrate(wall_observation(label=3, seed=5))
    files_a, files_b = (save_map_files(m, tmp_path / name) for m, name in ((a, "a"), (b, "b")))
    assert files_a == files_b
    for name in files_a:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert a.describe() == b.describe()


def test_state_names_are_the_schema_not_private_attributes(tmp_path):
    m = get_map(MapKind.OCTOMAP, _config(tmp_path), LabelSet.generic(4))
    m.integrate(wall_observation())
    assert not any(name.startswith("_") for name in m.state())


def test_a_state_that_does_not_fit_the_map_is_a_format_error(tmp_path):
    m = get_map(MapKind.OCTOMAP, _config(tmp_path), LabelSet.generic(4))
    state = m.state()
    del state["rgb"]
    with pytest.raises(FormatError, match="lacks rgb"):
        get_map(MapKind.OCTOMAP, _config(tmp_path), LabelSet.generic(4)).restore(state)
    bayes = get_map(MapKind.OCTOMAP, _config(tmp_path, fusion=FusionRule.BAYES), LabelSet.generic(4))
    with pytest.raises(FormatError, match="another configuration"):
        bayes.restore(m.state())


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("room-checkpoints")
    write_tum_sequence(root, make_room_frames(6), label_set=room_label_set())
    return root


def _run_config(room, out) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=room), mapping=MappingConfig(resolution=0.2),
                     output=OutputConfig(out=out, plots=False, preview=False))


def test_a_checkpoint_of_another_schema_version_is_named_and_the_run_starts_over(room, tmp_path, caplog):
    out = tmp_path / "out"
    stage = staging_folder(out)
    stage.mkdir()
    header, arrays = {"config": json.loads(_run_config(room, out).to_json())}, {"x": np.zeros(3)}
    write_checkpoint(stage / "checkpoint.npz", header, arrays)
    raw = dict(np.load(stage / "checkpoint.npz"))
    old = json.loads(raw["header"].tobytes())
    old["version"] = VERSION - 1
    np.savez(stage / "checkpoint.npz", header=np.frombuffer(json.dumps(old).encode(), np.uint8), x=np.zeros(3))
    with pytest.raises(FormatError, match=f"schema version {VERSION - 1}"):
        read_checkpoint(stage / "checkpoint.npz")
    with caplog.at_level(logging.WARNING, logger="semmap"):
        result = Pipeline(_run_config(room, out), resume=True).run()
    assert result.report["frames_used"] == 6
    lines = [r.getMessage() for r in caplog.records if "--resume" in r.getMessage()]
    assert len(lines) == 1 and f"schema version {VERSION - 1}" in lines[0] and "first frame" in lines[0]


def test_a_checkpoint_of_another_configuration_is_named_and_the_run_starts_over(room, tmp_path, caplog):
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        Pipeline(_run_config(room, out), checkpoint_every=2, progress=_stop_after(3)).run()
    assert (staging_folder(out) / "checkpoint.npz").is_file()
    changed = _run_config(room, out).model_copy(update={"mapping": MappingConfig(resolution=0.25)})
    with caplog.at_level(logging.WARNING, logger="semmap"):
        result = Pipeline(changed, resume=True).run()
    assert result.report["frames_used"] == 6
    assert any("another configuration" in r.getMessage() for r in caplog.records)


def _stop_after(n: int):
    """A progress wrapper that raises KeyboardInterrupt (as a crash would) once ``n`` frames were handed out."""

    def wrap(it, total):
        for i, item in enumerate(it):
            if i == n:
                raise KeyboardInterrupt
            yield item

    return wrap
