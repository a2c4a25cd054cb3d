"""Smoke test of the bad-input probe re-run harness (scripts/probes/run_cases.py): command splitting, the paths a
command names and the classification, in-process on strings (no semmap run, well under a second)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "probes"))

import run_cases as rc


def test_split_keeps_quotes_and_substitutions() -> None:
    cmd = ("echo '{\"a\": 1; 2}' > h/p.json; mkdir -p h/par && .venv/bin/semmap run $'h/s;\\xff' "
           "--out outputs/h/$(printf 'z%.0s' {1..3}); ls h")
    assert rc.split_segments(cmd) == ["echo '{\"a\": 1; 2}' > h/p.json", "mkdir -p h/par",
                                      ".venv/bin/semmap run $'h/s;\\xff' --out outputs/h/$(printf 'z%.0s' {1..3})",
                                      "ls h"]
    case = rc.Case("x", 0, 1.0, 100, 0, cmd, "")
    setup, measured = rc.plan(case)
    assert setup == ["echo '{\"a\": 1; 2}' > h/p.json", "mkdir -p h/par"] and measured.startswith(".venv/bin/semmap")


def test_paths_of_separates_inputs_and_outputs() -> None:
    words = ["SEMMAP_WEIGHTS=h/w/x", ".venv/bin/semmap", "view", "h/v.ot", "--save", "h/v.ot", "--plot=p.png"]
    assert rc.paths_of(words) == (["h/w/x", "view", "h/v.ot"], ["h/v.ot", "p.png"])


def test_classify() -> None:
    assert rc.classify(1, 200, False, [], "semmap: error: h/x.ot: file is empty\n")[0] == "GOOD"
    assert rc.classify(1, 200, False, [], "Traceback (most recent call last):\n  x\nOSError: [Errno 28]\n") == (
        "TRACEBACK", "OSError: [Errno 28]")
    assert rc.classify(0, 200, False, ["h/victim.ot"], "")[0] == "DATA-LOSS"
    assert rc.classify(139, 200, False, [], "")[0] == "SEGFAULT"
    assert rc.classify(124, 200, True, [], "")[0] == "HANG"
    assert rc.classify(1, 2000, False, [], "semmap: error: too big\n")[0] == "MEMORY"
    assert rc.classify(1, 200, False, [], "semmap: error: weights\n Re-running torch.load ...\n")[0] == "MULTI-LINE"
    assert rc.classify(1, 200, False, [], "semmap: error: x\nsemmap: WARNING: y\n")[0] == "GOOD"
    assert rc.classify(1, 200, False, [], "mapping ━━━ 0/3 -:--:--\n")[0] == "UNCLEAR"
    names = rc.names_of([".venv/bin/semmap", "run", "h/ds/x", "--out", "outputs/h/x", "--input-size", "9"])
    assert rc.classify(1, 200, False, [], "semmap: error: label 9 is outside the set\n", names)[0] == "NO-NAME"
    for named in ("h/ds/x/labels/0.png: bad", "invalid option input_size: too big", "--out: exists"):
        assert rc.classify(1, 200, False, [], f"semmap: error: {named}\n", names)[0] == "GOOD"


def test_fingerprint_sees_a_device_replaced_by_a_file(tmp_path: Path) -> None:
    f = tmp_path / "a"
    f.write_bytes(b"1")
    before = rc.snapshot(tmp_path, {"a": True, ".": True})
    f.write_bytes(b"2")
    assert rc.changes(before, rc.snapshot(tmp_path, {"a": True, ".": True})) == ["a", ". (a)"]


def test_the_new_surfaces_rows_and_their_classes() -> None:
    """The new-surfaces probe's rows end in its class; commands name the checkout as CHECKOUT/."""
    import surfaces

    assert rc.classify(130, 200, False, [], "")[0] == "UNCLEAR"  # Ctrl-C without a word (U8)
    assert rc.classify(130, 200, False, [], "semmap: interrupted\n")[0] == "GOOD"
    assert rc.classify(1, 200, False, [], "calibrate_weights: error: --out x: is a device\n")[0] == "GOOD"
    cases = {c.id: c for c in rc.read_cases(surfaces.TSV)} if surfaces.TSV.is_file() else {}
    if cases:
        assert cases["gr_points"].original_class() == "SILENT-WRONG" and cases["mg_T_huge"].probe_class == "TRACEBACK"
        assert f"{rc.REPO}/scripts/calibrate_weights.py" in cases["cal_garbage"].command
        assert not cases["gr_points"].output.endswith("SILENT-WRONG")
    assert surfaces.silent_fixed("gr_points", 0, "semmap: WARNING: a points map keeps no free space")
    assert not surfaces.silent_fixed("gr_points", 0, "o/g: 3x3 cells; free 0")
    assert surfaces.silent_fixed("sg_from_cwd", 0, "sg_cwd: 27 objects, 1 rooms (from the layout)")


def test_a_case_reading_a_fixture_the_table_does_not_make_is_not_reproduced() -> None:
    import surfaces

    made = {"runs/a", "h/T_far.txt"}
    assert surfaces.unbuilt(".venv/bin/semmap merge runs/a runs/a --out o/m --transform h/T_far.txt", made) == []
    assert surfaces.unbuilt("cd o && ../.venv/bin/semmap export grid ../runs/a --out sg", made) == []
    assert surfaces.unbuilt(".venv/bin/semmap run sim/a --segmenter onnx:h/onnx/tiny.onnx --out o/x", made) == [
        "sim/a", "h/onnx/tiny.onnx"]
    assert surfaces.unbuilt(".venv/bin/semmap run runs/a --segmenter onnx:h/nothere.onnx --out o/x", made) == []


def test_a_model_path_after_its_segmenter_name_counts_as_named() -> None:
    names = rc.names_of([".venv/bin/semmap", "run", "sim/a", "--segmenter", "onnx:runs/a/map.semmap"])
    assert "runs/a/map.semmap" in names and "onnx:runs/a/map.semmap" in names


def test_an_empty_word_is_no_input_path() -> None:
    assert rc.paths_of([".venv/bin/semmap", "run", "sim/a", "--dynamic", "", "--out", "o/d1"]) == (
        ["run", "sim/a"], ["o/d1"])
