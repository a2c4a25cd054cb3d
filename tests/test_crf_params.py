"""Issue 33, item 5: the 3D CRF's kernels are settable with ``--crf-params key=value,...`` and the run configuration
(``crf.*``); SemanticFusion's values are one preset; a bad key or value is refused in one line naming the option."""

from __future__ import annotations

import sys
from unittest import mock

import pytest
from typer.testing import CliRunner

from semmap import cli
from semmap.config import CrfConfig
from semmap.errors import ConfigError
from semmap.fusion.crf import CRF_KEYS, SEMANTICFUSION, CrfParams, parse_crf_params


def test_keys_parse_into_the_configuration_and_its_params() -> None:
    values = parse_crf_params("appearance_weight=10, smoothness-normal-std=0.1,iterations=8")
    assert values == {"appearance_weight": 10.0, "smoothness_normal_std": 0.1, "iterations": 8}
    params = CrfConfig(enabled=True, **values).params()
    assert (params.appearance_weight, params.smoothness_normal_std, params.iterations) == (10.0, 0.1, 8)
    assert params.smoothness_weight == CrfParams().smoothness_weight  # keys not given keep the defaults
    assert CrfConfig().params() == CrfParams()
    assert set(CRF_KEYS) <= set(CrfConfig.model_fields)


def test_the_semanticfusion_preset_and_overrides_after_it() -> None:
    sf = CrfConfig(**parse_crf_params("semanticfusion")).params()
    assert sf == SEMANTICFUSION
    assert (sf.appearance_weight, sf.smoothness_weight, sf.appearance_position_std, sf.appearance_color_std,
            sf.smoothness_normal_std) == (10.0, 3.0, 0.05, 20.0, 0.1)
    assert CrfConfig(**parse_crf_params("semanticfusion,iterations=3")).params().iterations == 3
    assert parse_crf_params(None) == parse_crf_params("") == {}


@pytest.mark.parametrize(("text", "message"), [
    ("apperance_weight=3", r"--crf-params: unknown key 'apperance_weight'; keys: iterations, appearance_weight"),
    ("appearance_weight", r"--crf-params: 'appearance_weight' is neither key=value nor a preset"),
    ("smoothness_weight=lots", r"--crf-params: smoothness_weight must be a number, got 'lots'"),
])
def test_bad_keys_and_texts_are_refused_naming_the_option(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_crf_params(text)


@pytest.mark.parametrize(("text", "message"), [
    ("appearance_weight=-1", r"--crf-params \(crf.appearance_weight\) must be a number from 0 to 1,000"),
    ("smoothness_normal_std=nan", r"--crf-params \(crf.smoothness_normal_std\) must be a finite number"),
    ("appearance_position_std=0", r"--crf-params \(crf.appearance_position_std\) must be a number from 0.001"),
    ("iterations=2.5", r"--crf-params \(crf.iterations\) must be a whole number from 1 to 50"),
])
def test_values_out_of_range_are_refused_in_one_line_by_the_cli(text: str, message: str, tmp_path) -> None:
    with pytest.raises(ConfigError, match=message):
        CrfConfig(**parse_crf_params(text))
    args = ["semmap", "run", str(tmp_path / "nowhere"), "--out", str(tmp_path / "out"), "--crf",
            f"--crf-params={text}"]
    with CliRunner().isolation() as (_, err, _), mock.patch.object(sys, "argv", args), \
            pytest.raises(SystemExit) as exit_:
        try:
            cli.main()
        finally:
            sys.stderr.flush()
            text_out = err.getvalue().decode()
    assert exit_.value.code == 1
    lines = [line for line in text_out.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("semmap: error:") and "--crf-params" in lines[0], text_out
