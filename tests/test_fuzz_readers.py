"""Every reader fuzzed with hypothesis: valid files written by semmap, damaged (bytes flipped, cut, inserted,
repeated) or replaced by random bytes, give a result or a SemmapError, never another exception. The same targets
run for longer under atheris in ``scripts/fuzz_readers.py``."""

from __future__ import annotations

import importlib.util
import logging
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "fuzz_readers.py"
_spec = importlib.util.spec_from_file_location("_fuzz_readers", SCRIPT)
fuzz = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fuzz)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz")
    logging.getLogger("semmap").setLevel(logging.CRITICAL)  # thousands of warnings about damaged frames
    yield folder
    logging.getLogger("semmap").setLevel(logging.NOTSET)


@pytest.fixture(scope="module")
def seeds(workdir):
    return fuzz.seed_files(workdir / "seeds")


@st.composite
def damaged(draw, seed: bytes) -> bytes:
    """``seed`` with a few byte-level edits, or random bytes."""
    if draw(st.integers(0, 5)) == 0:
        return draw(st.binary(max_size=600))
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 6))):
        pos = draw(st.integers(0, max(len(data) - 1, 0)))
        op = draw(st.sampled_from(("set", "cut", "insert", "repeat", "truncate")))
        if op == "set" and data:
            data[pos] = draw(st.integers(0, 255))
        elif op == "cut":
            del data[pos:pos + draw(st.integers(1, 16))]
        elif op == "insert":
            data[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        elif op == "repeat":
            data[pos:pos] = data[pos:pos + draw(st.integers(1, 64))] * draw(st.integers(1, 4))
        else:
            del data[pos:]
    return bytes(data)


EXAMPLES = {"octomap": 40, "octomap_bt": 30, "semmap": 30, "ply": 30, "trajectory": 40, "labelset": 30,
            "sevenscenes_pose": 25, "tum_index": 20, "rosbag": 15, "scannet_sens": 30, "replica_traj": 20}


def test_every_reader_has_a_fuzz_target():
    assert set(EXAMPLES) == set(fuzz.TARGETS)


@pytest.mark.parametrize("target", list(EXAMPLES))
def test_damaged_files_give_a_result_or_a_semmap_error(target, seeds, workdir):
    @settings(max_examples=EXAMPLES[target], deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(damaged(seeds[target]))
    def check(data: bytes) -> None:
        fuzz.run_target(target, data, workdir)

    fuzz.TARGETS[target](seeds[target], workdir)  # the undamaged seed reads back without error
    check()
