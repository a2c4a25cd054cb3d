"""`semmap demo` writes the same map files, byte for byte, and the same report numbers (timings aside) as it did
before the architecture change (tests/data/demo_digest.json, made at 7a5da7d with the oracle segmenter, which
is deterministic on every machine; the shipped network's ONNX Runtime output may differ between CPUs)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from semmap.runner import run_demo

DIGEST = Path(__file__).parent / "data" / "demo_digest.json"
TIMINGS = {"ms_per_frame", "startup_s", "segmenter_startup_s", "peak_rss_mb", "frames_per_second"}
#: What the map holds in memory changed on purpose (hash tables start small and grow: issue 30, item 7); it may
#: only shrink.
MEMORY = ("bytes_in_memory", "bytes_per_voxel_in_memory")


@pytest.mark.slow
def test_demo_writes_the_stored_map_bytes_and_report_numbers(tmp_path):
    stored = json.loads(DIGEST.read_text())
    result = run_demo(out=tmp_path / "demo", frames=20, oracle=True, cloud=True)  # (the digest has cloud.ply)
    for name, digest in stored["sha256"].items():
        assert hashlib.sha256((result.out_dir / name).read_bytes()).hexdigest() == digest, name
    report = {k: v for k, v in result.report.items() if k not in TIMINGS}
    for key in MEMORY:
        assert report.pop(key) <= stored["report"].pop(key), key
    assert {k: v for k, v in report.items() if k in stored["report"]} == stored["report"]  # (new keys may come)
