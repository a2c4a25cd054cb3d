"""benchmarks/perf_guard.py's verdicts: which stage fails, which an allow-list reason excuses (no timing)."""

from __future__ import annotations

import pytest

from script_modules import load_script

guard = load_script("benchmarks/perf_guard.py")


def verdicts(base, work, allow=(), tolerance=0.10, min_ms=0.5):
    rows = guard.compare(base, work, tolerance=tolerance, allow=list(allow), min_ms=min_ms)
    return {r.stage: r.verdict for r in rows}


def test_a_stage_more_than_the_tolerance_slower_fails_unless_the_allow_list_names_it():
    base = {"octree/consecutive/0.05/attributes": 1.0, "octree/consecutive/0.05/raycast": 2.0, "demo/total": 80.0}
    work = {"octree/consecutive/0.05/attributes": 1.2, "octree/consecutive/0.05/raycast": 2.19, "demo/total": 60.0}
    assert verdicts(base, work) == {"octree/consecutive/0.05/attributes": "slower",
                                    "octree/consecutive/0.05/raycast": "ok", "demo/total": "ok"}
    rows = guard.compare(base, work, tolerance=0.10, allow=[("octree/*/attributes", "mean evidence")], min_ms=0.5)
    allowed = [r for r in rows if r.verdict == "allowed"]
    assert [(r.stage, r.reason) for r in allowed] == [("octree/consecutive/0.05/attributes", "mean evidence")]
    assert guard.failures(rows) == []
    assert allowed[0].ratio == pytest.approx(1.2)


def test_stages_too_short_to_time_and_stages_of_one_tree_never_fail():
    v = verdicts({"demo/collect": 0.1, "demo/cloud": 20.0}, {"demo/collect": 0.4, "online/0.05/track": 9.0})
    assert v == {"demo/collect": "short", "demo/cloud": "gone", "online/0.05/track": "new"}


def test_each_stage_keeps_its_best_time_over_the_rounds():
    assert guard.best_of([{"a": 3.0, "b": 1.0}, {"a": 2.0}, {"b": 4.0, "c": 5.0}]) == {"a": 2.0, "b": 1.0, "c": 5.0}


def test_the_allow_list_needs_a_reason_on_every_line(tmp_path):
    path = tmp_path / "allow.txt"
    path.write_text("# stages that may be slower\ndemo/segment   the demo's network is larger now  # issue 32\n\n")
    assert guard.read_allow(path) == [("demo/segment", "the demo's network is larger now")]
    path.write_text("demo/segment\n")
    with pytest.raises(SystemExit, match="no reason"):
        guard.read_allow(path)
    assert guard.read_allow(tmp_path / "missing.txt") == []


def test_stage_names_come_from_the_octree_bench_and_the_run_report():
    bench = {"results": [{"resolution": 0.05, "semmap_ms": 4.0, "semmap_stage_ms": {"attributes": 1.0}}],
             "sparse_results": [{"resolution": 0.02, "semmap_ms": 30.0, "semmap_stage_ms": {}}]}
    assert guard.octree_stages(bench) == {"octree/consecutive/0.05/total": 4.0,
                                          "octree/consecutive/0.05/attributes": 1.0,
                                          "octree/sparse/0.02/total": 30.0}
    report = {"ms_per_frame": {"segment": 20.0, "total": 50.0}, "frames_per_second": 25.0}
    assert guard.report_stages(report, "online/0.05") == {"online/0.05/segment": 20.0, "online/0.05/total": 50.0,
                                                          "online/0.05/frame": 40.0}
    assert guard.last_json('progress\n{"bench": 1}\n') == {"bench": 1}
