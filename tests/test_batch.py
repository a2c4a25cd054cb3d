"""`semmap batch`: sequences as Ray tasks on a local cluster of 2 workers and on two Ray nodes joined by address,
outputs identical to separate runs, resuming a half-finished batch, and the summary table."""

from __future__ import annotations

import json

import pytest

from semmap.batch import Status, config_for, is_complete, plan, run_batch, write_summary
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
from semmap.runner import run_config
from semmap.sim.export import simulate_sequence

MAP_FILES = ("map.ot", "map.bt", "map.semmap", "trajectory.txt")


@pytest.fixture(scope="module")
def sequences(tmp_path_factory):
    root = tmp_path_factory.mktemp("batch-seqs")
    return [simulate_sequence(root / f"seq{i}", scene_seed=i, kind="office", size="small", trajectory="desk",
                              frames=8) for i in range(2)]


def _template(out) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=out), mapping=MappingConfig(resolution=0.1),
                     output=OutputConfig(out=out, plots=False))


@pytest.fixture(scope="module")
def separate(sequences, tmp_path_factory):
    """Each sequence mapped by itself, as `semmap run` does."""
    root = tmp_path_factory.mktemp("separate")
    for seq in sequences:
        config = _template(root)
        config = config.model_copy(update={"input": InputConfig(dataset=seq),
                                           "output": OutputConfig(out=root / seq.name, plots=False)})
        run_config(config)
    return root


def _same_outputs(a, b) -> None:
    for name in MAP_FILES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), (a, name)
    ra, rb = (json.loads((d / "report.json").read_text()) for d in (a, b))
    timing = {"ms_per_frame", "startup_s", "segmenter_startup_s", "peak_rss_mb", "frames_per_second"}
    assert {k: v for k, v in ra.items() if k not in timing} == {k: v for k, v in rb.items() if k not in timing}


@pytest.fixture
def local_cluster():
    """A local Ray cluster of 2 workers for the whole test (run_batch joins it instead of starting its own)."""
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.mark.slow
def test_local_cluster_maps_every_sequence_like_separate_runs_and_resumes(sequences, separate, tmp_path,
                                                                          local_cluster):
    out = tmp_path / "batch"
    items = plan(sequences, out)
    result = run_batch(_template(out), items, workers=2, cpus_per_run=1)
    assert [r.status for r in result.rows] == [Status.DONE, Status.DONE]
    for seq in sequences:
        _same_outputs(out / seq.name, separate / seq.name)
    write_summary(out, result)
    summary = json.loads((out / "batch.json").read_text())
    assert summary["done"] == 2 and summary["seconds_per_sequence"] > 0
    assert "| seq0 | done | 8 |" in (out / "batch.md").read_text()
    # half-finished: the second sequence lost its report (a run killed before its end)
    (out / sequences[1].name / "report.json").unlink()
    again = run_batch(_template(out), items, workers=2, cpus_per_run=1)
    assert [r.status for r in again.rows] == [Status.RESUMED, Status.DONE]
    assert again.rows[0].seconds == result.rows[0].seconds  # the earlier time of the skipped sequence is kept
    _same_outputs(out / sequences[1].name, separate / sequences[1].name)
    changed = _template(out).model_copy(update={"mapping": MappingConfig(resolution=0.2)})
    assert is_complete(config_for(_template(out), items[0]))
    assert not is_complete(config_for(changed, items[0]))  # outputs of another configuration are not "done"


@pytest.mark.slow
def test_two_ray_nodes_joined_by_address_share_the_batch(sequences, separate, tmp_path):
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        out = tmp_path / "two-nodes"
        result = run_batch(_template(out), plan(sequences, out), address=cluster.address, cpus_per_run=1)
        assert result.nodes == 2 and [r.status for r in result.rows] == [Status.DONE, Status.DONE]
        assert len({r.node for r in result.rows}) == 2  # one CPU per node: the two runs went to different nodes
        for seq in sequences:
            _same_outputs(out / seq.name, separate / seq.name)
    finally:
        cluster.shutdown()
