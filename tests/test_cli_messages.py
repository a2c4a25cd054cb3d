"""First-contact messages: an error names the option or file the user typed, and a partly failed batch says so."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from semmap.batch import BatchResult, BatchRow, Status
from semmap.cli import app
from semmap.errors import SemmapError
from semmap.sim.export import simulate_sequence


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    return simulate_sequence(tmp_path_factory.mktemp("seq") / "seq", frames=2, image_size=(80, 60), scene_seed=3)


@pytest.mark.slow
@pytest.mark.parametrize(("section", "values", "named"), [
    ("mapping", {"resolution": 1e300}, "resolution"),
    ("semantics", {"k": 99}, "semantics.k"),
    ("online", {"max_pending": 0}, "online.max_pending"),
])
def test_batch_config_errors_name_the_config_file(sequence: Path, tmp_path: Path, section, values, named) -> None:
    config = tmp_path / "my-config.json"
    config.write_text(json.dumps({"input": {"dataset": str(sequence)}, section: values,
                                  "output": {"out": str(tmp_path / "o")}}))
    result = CliRunner().invoke(app, ["batch", str(sequence), "--out", str(tmp_path / "out"), "--config", str(config)])
    assert isinstance(result.exception, SemmapError)
    message = str(result.exception)
    assert message.startswith(f"{config}: ") and named in message and "\n" not in message
    assert not (tmp_path / "out").exists()


def test_a_batch_with_a_failed_sequence_ends_with_one_error_line(sequence: Path, tmp_path: Path, monkeypatch) -> None:
    def fake_run_batch(template, items, **kwargs) -> BatchResult:
        rows = [BatchRow(sequence=i.name, dataset=str(i.dataset), out=str(i.out),
                         status=Status.FAILED if k else Status.DONE, error="broken" if k else None)
                for k, i in enumerate(items)]
        return BatchResult(rows=rows, seconds=1.0, address="local", nodes=1)

    monkeypatch.setattr("semmap.batch.run_batch", fake_run_batch)
    other = tmp_path / "other"
    other.mkdir()
    result = CliRunner().invoke(app, ["batch", str(sequence), str(other), "--out", str(tmp_path / "out")])
    assert isinstance(result.exception, SemmapError)
    assert str(result.exception) == f"1 of 2 sequences failed; see {tmp_path / 'out' / 'batch.md'}"
    assert (tmp_path / "out" / "batch.md").is_file()
