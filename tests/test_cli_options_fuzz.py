"""Issue 31, deliverables 3 and 8: every numeric option of every command has a limit in ``semmap.limits``, the
configuration and the library check the same table, and hypothesis drives the options as it drives the readers.

A refused value gives one ``semmap: error:`` line naming the option (exit 1), or the option parser's usage error
(exit 2) for text that is no number at all; never a traceback. An accepted value is stopped right after the check
(no command does any work here), so the whole file runs in seconds.
"""

from __future__ import annotations

import math
import re
import sys
import types
import typing
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import typer
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from semmap import cli, config, limits
from semmap.errors import ConfigError

#: Options of type str that hold no numbers (names, choices, topics, addresses); a new str option must be listed
#: here or have a rule in ``semmap.limits.OPTIONS``.
TEXT_OPTIONS = frozenset({
    "--format", "--rgb-topic", "--depth-topic", "--camera-info-topic", "--pose-topic", "--world-frame",
    "--camera-frame", "--semantics", "--segmenter", "--backend", "--poses", "--color-mode", "--maps", "--fusion",
    "--state-dtype", "--instances", "--instance-errors", "--kind", "--size", "--trajectory", "--model", "--backbone",
    "--device", "--method", "--init", "--mode", "--motion", "--address", "--no-go", "--gt-label-property",
    "--dynamic", "--realism",
    # key=value text: each number is checked by its own field of the configuration (crf.*), which names the option
    # (tests/test_crf_params.py)
    "--crf-params",
    # an axis name or a direction x,y,z: parse_up refuses a non-finite or zero vector (tests/test_structure.py)
    "--up",
    "--gt-classes",
})
#: The required arguments of each command: paths that are never opened (the numbers are checked first).
NOWHERE = "/nonexistent/semmap-fuzz"
REQUIRED = {
    "run": [f"{NOWHERE}/seq", "--out", f"{NOWHERE}/out"],
    "simulate": ["--out", f"{NOWHERE}/out"],
    "demo": ["--out", f"{NOWHERE}/out"],
    "train": ["--model", "fcn", "--data", f"{NOWHERE}/data", "--out", f"{NOWHERE}/out"],
    "adapt": [f"{NOWHERE}/run", "--out", f"{NOWHERE}/out"],
    "track": [f"{NOWHERE}/seq", "--out", f"{NOWHERE}/t.txt"],
    "localize": [f"{NOWHERE}/map.semmap", f"{NOWHERE}/seq", "--out", f"{NOWHERE}/out"],
    "eval-traj": [f"{NOWHERE}/gt.txt", f"{NOWHERE}/est.txt"],
    "eval-seg": [f"{NOWHERE}/pred", f"{NOWHERE}/gt"],
    "info": [f"{NOWHERE}/map.ot"],
    "batch": [f"{NOWHERE}/seq", "--out", f"{NOWHERE}/out"],
    "view": [f"{NOWHERE}/map.ot"],
    "eval-map": [f"{NOWHERE}/map.semmap", f"{NOWHERE}/seq"],
    "diff": [f"{NOWHERE}/a.semmap", f"{NOWHERE}/b.semmap", "--out", f"{NOWHERE}/out"],
    "merge": [f"{NOWHERE}/a.semmap", f"{NOWHERE}/b.semmap", "--out", f"{NOWHERE}/out"],
    "export grid": [f"{NOWHERE}/map.semmap", "--out", f"{NOWHERE}/out"],
    "export esdf": [f"{NOWHERE}/map.semmap", "--out", f"{NOWHERE}/out"],
    "export mesh": [f"{NOWHERE}/run", "--out", f"{NOWHERE}/out"],
    "export scene-graph": [f"{NOWHERE}/run", "--out", f"{NOWHERE}/out"],
}


def _base_type(annotation: object) -> object:
    """``int`` of ``int | None``; ``list`` of ``list[Path]``."""
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType) and len(args) == 1:
        return _base_type(args[0])
    return typing.get_origin(annotation) or annotation


#: The click commands of the app, built once (typer builds them again on every call, 90 % of a call's time).
COMMANDS = typer.main.get_command(cli.app)


def _commands() -> list[tuple[str, object]]:
    """(name, click command) of every command, sub-apps' commands as ``export grid``."""
    out = []
    for name, command in COMMANDS.commands.items():
        subs = getattr(command, "commands", None)
        out += [(f"{name} {sub}", c) for sub, c in subs.items()] if subs else [(name, command)]
    return out


def _options() -> list[tuple[str, str, object, object]]:
    """(command, --option, base type, default) of every option of every command."""
    rows = []
    for name, command in _commands():
        for p in command.params:
            if p.opts[0].startswith("-") and not p.is_flag:
                long = next(o for o in p.opts if o.startswith("--"))
                rows.append((name, long, _base_type(p.type_descriptor.annotation), p.default))
    return rows


OPTIONS = _options()
NUMERIC = [(c, o, t) for c, o, t, _ in OPTIONS if limits.option_rule(o, c) is not None]


# ------------------------------------------------------------------------------------------- structure
def test_every_numeric_option_has_a_limit() -> None:
    """A number-typed option, or a text option not known to hold only names, must have a rule in the table."""
    missing = [f"{c} {o}" for c, o, t, _ in OPTIONS
               if (t in (int, float) or (t is str and o not in TEXT_OPTIONS)) and limits.option_rule(o, c) is None]
    assert not missing, f"numeric options without an entry in semmap.limits.OPTIONS: {missing}"
    assert {c for c, _, _ in NUMERIC} >= {"run", "simulate", "demo", "train", "track", "localize", "eval-traj",
                                          "eval-seg", "batch"}


def test_every_rule_is_an_option_and_names_a_limit() -> None:
    used = {o for _, o, _ in NUMERIC} | {f"{c} {o}" for c, o, _ in NUMERIC}
    assert set(limits.OPTIONS) <= used, set(limits.OPTIONS) - used
    assert {rule.limit for rule in limits.OPTIONS.values()} <= set(limits.LIMITS)
    assert not TEXT_OPTIONS & {o for _, o, _ in NUMERIC}


@pytest.mark.parametrize("command, option, default", [(c, o, d) for c, o, _, d in OPTIONS
                                                      if limits.option_rule(o, c) is not None])
def test_every_default_is_within_its_limit(command, option, default) -> None:
    limits.check_option(option, default, command)


def _config_sections() -> list[type]:
    return [cls for cls in vars(config).values()
            if isinstance(cls, type) and issubclass(cls, config._Section) and cls is not config._Section]


def _limited_fields() -> list[tuple[type, str, str]]:
    """(section, field, limit) of every field of the run configuration with a limit."""
    rows = []
    for cls in _config_sections():
        for name, field in cls.model_fields.items():
            extra = field.json_schema_extra
            if isinstance(extra, dict) and "limit" in extra:
                rows.append((cls, name, extra["limit"]))
    return rows


def test_every_number_of_the_configuration_has_a_limit() -> None:
    """Every int or float field (input_size: its own check of the same table) takes its bounds from the table."""
    limited = {(cls, name) for cls, name, _ in _limited_fields()}
    numbers = {(cls, name) for cls in _config_sections() for name, f in cls.model_fields.items()
               if _base_type(f.annotation) in (int, float)}
    assert numbers - limited == set()
    for cls, name, limit in _limited_fields():
        meta = {type(m).__name__: m for m in cls.model_fields[name].metadata}
        assert (meta["Ge"].ge, meta["Le"].le) == (limits.LIMITS[limit].lo, limits.LIMITS[limit].hi)


# ------------------------------------------------------------------------------------------- the oracle
def _within(limit: str, number: object) -> bool:
    """Independently of ``limits.check``: a finite number within the limit (whole where it counts)."""
    lim = limits.LIMITS[limit]
    try:
        x = float(number)
    except (TypeError, ValueError, OverflowError):
        return False
    if not math.isfinite(x) or not lim.lo <= x <= lim.hi:
        return False
    return not lim.integer or x == int(x)


def _valid(rule: limits.OptionRule, value: object) -> bool:
    """Whether ``value`` (as the command received it) lies within ``rule``."""
    if rule.form == limits.NUMBER:
        return _within(rule.limit, value)
    text = str(value)
    if rule.form in limits.NUMBER_LISTS:
        parts = text.replace(",", " ").split()
        return len(parts) == limits.NUMBER_LISTS[rule.form][0] and all(_within(rule.limit, p) for p in parts)
    if rule.form == limits.BYTES:
        m = re.fullmatch(r"\s*(\d*\.?\d+(?:e\d+)?)\s*([KMGT]?)(?:i?B)?\s*", text, re.IGNORECASE)
        return m is not None and _within(rule.limit, float(m.group(1)) * 1024 ** " KMGT".index(m.group(2).upper()
                                                                                             or " "))
    sides = text.lower().split("x")
    if (len(sides) == 1 and rule.form != limits.SIDE_OR_SIZE) or len(sides) > 2:
        return False
    try:
        return all(_within(rule.limit, int(s)) for s in sides)
    except ValueError:
        return False


# ------------------------------------------------------------------------------------------- values
SPECIAL = ["nan", "NaN", "inf", "-inf", "Infinity", "0", "-0", "-1", "0.5", "-0.5", "1e300", "-1e300", "1e-300",
           "9" * 25, "-" + "9" * 25, "9" * 400, "abc", "", " ", "1,5", "0x10", "1e3"]


def _number_texts(limit: str, kind: object) -> st.SearchStrategy[str]:
    """Texts of numbers around and within ``limit``: its ends, just beyond them, values inside, special cases."""
    lim = limits.LIMITS[limit]
    if kind is int or lim.integer:
        lo, hi = int(lim.lo), int(lim.hi)
        inside = st.integers(lo, hi).map(str)
        edges = st.sampled_from([str(lo), str(hi), str(lo - 1), str(hi + 1)])
    else:
        inside = st.floats(lim.lo, lim.hi, allow_nan=False).map(repr)
        step = max(abs(lim.lo), abs(lim.hi), 1.0) * 1e-3
        edges = st.sampled_from([repr(lim.lo), repr(lim.hi), repr(lim.lo - step), repr(lim.hi + step)])
    return st.one_of(st.sampled_from(SPECIAL), edges, inside)


def _texts(rule: limits.OptionRule, kind: object) -> st.SearchStrategy[str]:
    number = _number_texts(rule.limit, kind)
    side = _number_texts(rule.limit, int)
    if rule.form == limits.NUMBER:
        return number
    if rule.form == limits.SIZE:
        return st.one_of(st.tuples(side, side).map("x".join), st.sampled_from([*SPECIAL, "x", "16x", "nanx16"]))
    if rule.form == limits.SIDE_OR_SIZE:
        return st.one_of(side, st.tuples(side, side).map("x".join), st.sampled_from(["x", "16x", "16x16x16"]))
    if rule.form in limits.NUMBER_LISTS:
        n = limits.NUMBER_LISTS[rule.form][0]
        unit = st.sampled_from(["0", "0.5", "1", "-2.5", "1e3"])
        return st.one_of(st.lists(unit, min_size=n, max_size=n).map(" ".join),
                         st.lists(number, min_size=n, max_size=n).map(" ".join),
                         st.lists(unit, min_size=0, max_size=n + 2).map(" ".join), st.sampled_from(SPECIAL))
    sizes = st.tuples(st.sampled_from(["0", "1", "512", "1.5", "4", "1023", "1e400", "-1", "nan", ""]),
                      st.sampled_from(["", "K", "M", "G", "T", "GB", "X"])).map("".join)
    return st.one_of(sizes, st.sampled_from(SPECIAL))


# ------------------------------------------------------------------------------------------- the CLI in-process
class CheckedError(Exception):
    """The command's numbers passed the check; it stops here instead of doing any work."""

    def __init__(self, values: dict) -> None:
        super().__init__("checked")
        self.values = values


def invoke(args: list[str]) -> tuple[int | None, str, dict | None]:
    """Run ``semmap ARGS`` through ``semmap.cli.main`` in this process: (exit code, stderr and stdout, the values
    of the options when the check passed, else None). Any exception but SystemExit fails the test."""
    real = limits.check_options

    def stop_after_check(command: str, values: dict) -> None:
        real(command, values)
        raise CheckedError(values)

    with mock.patch.object(limits, "check_options", stop_after_check), \
            mock.patch.object(typer.main, "get_command", lambda _: COMMANDS), \
            CliRunner().isolation(env={"COLUMNS": "200", "TERM": "dumb"}) as (out, err, _), \
            mock.patch.object(sys, "argv", ["semmap", *args]):
        try:
            cli.main()
            code, values = 0, None
        except SystemExit as exc:
            code, values = exc.code, None
        except CheckedError as exc:
            code, values = None, exc.values
        sys.stdout.flush()
        sys.stderr.flush()
        text = err.getvalue().decode(errors="replace") + out.getvalue().decode(errors="replace")
    return code, text, values


def _assert_one_outcome(command: str, option: str, rule: limits.OptionRule, text: str) -> None:
    code, output, values = invoke([*command.split(), *REQUIRED[command], f"{option}={text}"])
    if values is not None:  # accepted: what the command received lies within the limit
        assert _valid(rule, values[option]), (option, text, values[option])
        return
    assert not _valid(rule, text), f"{command} {option}={text!r} is within the limit but refused: {output}"
    if code == 1:
        lines = [line for line in output.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith(f"semmap: error: {option} "), output
    else:  # text the option parser cannot read as a number: its usage error names the option
        assert code == 2 and f"'{option}'" in output and "Traceback" not in output, (code, output)


@pytest.fixture(autouse=True)
def _no_budget_left_behind():
    yield
    limits.set_memory_budget(None)


@pytest.mark.slow
@pytest.mark.parametrize("command, option, kind", NUMERIC, ids=[f"{c} {o}" for c, o, _ in NUMERIC])
def test_every_numeric_option_is_refused_in_one_line_or_accepted_within_its_limit(command, option, kind) -> None:
    rule = limits.option_rule(option, command)

    @settings(max_examples=10, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(_texts(rule, kind))
    def check(text: str) -> None:
        _assert_one_outcome(command, option, rule, text)

    check()


@pytest.mark.parametrize("command, option, kind", NUMERIC, ids=[f"{c} {o}" for c, o, _ in NUMERIC])
def test_nan_infinity_and_nonsense_never_pass(command, option, kind) -> None:
    rule = limits.option_rule(option, command)
    for text in ("nan", "inf", "-inf", "1e300", "-" + "9" * 25, "abc", ""):
        _assert_one_outcome(command, option, rule, text)


def test_an_accepted_value_reaches_the_command_as_given() -> None:
    code, _, values = invoke(["run", *REQUIRED["run"], "--resolution=0.1", "--top-k=2", "--input-size=320x240"])
    assert code is None and values["--resolution"] == 0.1 and values["--top-k"] == 2
    assert values["--input-size"] == "320x240"


# ------------------------------------------------------------------------------------------- the configuration
LIMITED_FIELDS = _limited_fields()


def _section(cls: type, **values):
    """One section of the run configuration (``dataset`` / ``out`` filled in; ``max_depth`` above any
    ``min_depth``)."""
    extra = {"dataset": Path("x")} if "dataset" in cls.model_fields else {}
    extra |= {"out": Path("o")} if "out" in cls.model_fields else {}
    if "min_depth" in values:
        extra["max_depth"] = limits.LIMITS["max_depth"].hi
    if "max_depth" in values:
        extra["min_depth"] = 0.0
    return cls(**extra, **values)


@pytest.mark.parametrize("cls, name, limit", LIMITED_FIELDS,
                         ids=[f"{cls.section}.{name}" for cls, name, _ in LIMITED_FIELDS])
def test_the_configuration_refuses_what_the_table_refuses_naming_the_field(cls, name, limit) -> None:
    lim = limits.LIMITS[limit]
    numbers = st.one_of(st.sampled_from([math.nan, math.inf, -math.inf, 0, -1, 1e300, 1e-300, 10**30, -(10**30),
                                         lim.lo, lim.hi, "abc", ""]),
                        st.integers(int(lim.lo), int(lim.hi)) if lim.integer else st.floats(lim.lo, lim.hi))

    @settings(max_examples=12, deadline=None, derandomize=True, database=None)
    @given(numbers)
    def check(value) -> None:
        assume(not (name == "min_depth" and value == lim.hi))  # no max_depth lies beyond it: a rule across fields
        if _within(limit, value) and not isinstance(value, str):
            _section(cls, **{name: value})
        else:
            with pytest.raises(ConfigError, match=rf"^(--[a-z-]+ \()?{cls.section}\.{name}\)? must be "):
                _section(cls, **{name: value})

    check()


@pytest.mark.parametrize("value", [(20000, 240), (320, math.nan), 8, math.inf, "abc"])
def test_the_configuration_refuses_a_bad_input_size(value) -> None:
    with pytest.raises(ConfigError, match=r"^--input-size \(semantics\.input_size\) must be "):
        config.SemanticsConfig(input_size=value)


def test_a_run_configuration_read_from_json_is_checked_too() -> None:
    text = '{"input": {"dataset": "x"}, "output": {"out": "o"}, "mapping": {"resolution": 1e300}}'
    with pytest.raises(ConfigError, match=r"--resolution \(mapping\.resolution\) must be a number from 0\.001"):
        config.RunConfig.model_validate_json(text)


# ------------------------------------------------------------------------------------------- the library
def _localize_options(**kwargs):
    from semmap.localization.sequence import LocalizeOptions

    return LocalizeOptions(**kwargs)


def _train_settings(tmp_path: Path, **kwargs):
    from semmap.train.trainer import TrainSettings

    return TrainSettings(model="fcn", data=(tmp_path,), out=tmp_path / "t", **kwargs)


@pytest.mark.parametrize("kwargs, option", [
    ({"height": 1e6}, "--height"), ({"pitch_deg": 720.0}, "--pitch-deg"), ({"motion_noise": 1e300}, "--motion-noise"),
    ({"points": 10**9}, "--points"), ({"stride": 0}, "--stride"), ({"max_frames": -1}, "--max-frames"),
    ({"seed": -1}, "--seed"), ({"init_pose": np.diag([1.0, 1.0, 1.0, 1.0]) + np.eye(4, k=3) * 1e6}, "--init-pose"),
])
def test_localize_options_take_the_table(kwargs, option) -> None:
    with pytest.raises(ConfigError, match=f"^{option} must be "):
        _localize_options(**kwargs)


@pytest.mark.parametrize("kwargs, option", [
    ({"width": 0.0}, "--width"), ({"width": math.nan}, "--width"), ({"threads": 0}, "--threads"),
    ({"eval_every": 0}, "--eval-every"), ({"seed": 2**40}, "--seed"), ({"depth": 20}, "--resnet-depth"),
])
def test_train_settings_take_the_table(tmp_path, kwargs, option) -> None:
    with pytest.raises(ConfigError, match=f"^{option} must be "):
        _train_settings(tmp_path, **kwargs)


def test_the_commands_library_functions_check_their_numbers(tmp_path) -> None:
    """What the CLI calls refuses bad numbers itself, before reading anything."""
    from semmap.datasets import open_dataset
    from semmap.eval.segmentation import evaluate_label_folders
    from semmap.runner import evaluate_trajectories, run_config, run_demo
    from semmap.sim.export import simulate_sequence

    cases = [
        (lambda: open_dataset(tmp_path, stride=0), "--stride"),
        (lambda: open_dataset(tmp_path, max_frames=math.nan), "--max-frames"),
        (lambda: open_dataset(tmp_path, max_frames=-1), "--max-frames"),
        (lambda: evaluate_label_folders(tmp_path, tmp_path, 1), "--num-classes"),
        (lambda: evaluate_label_folders(tmp_path, tmp_path, 2, ignore=70000), "--ignore"),
        (lambda: evaluate_trajectories(tmp_path / "gt", [tmp_path / "e"], max_time_diff=math.inf), "--max-time-diff"),
        (lambda: evaluate_trajectories(tmp_path / "gt", [tmp_path / "e"], rotation_frames=0), "--rotation-frames"),
        (lambda: run_config(config.RunConfig(input=config.InputConfig(dataset=tmp_path),
                                             output=config.OutputConfig(out=tmp_path / "o")), checkpoint_every=-1),
         "--checkpoint-every"),
        (lambda: run_demo(out=tmp_path / "d", frames=0), "--frames"),
        (lambda: run_demo(out=tmp_path / "d", scene_seed=-1), "--scene-seed"),
        (lambda: simulate_sequence(tmp_path / "s", frames=1, scene_seed=-1), "--scene-seed"),
        (lambda: simulate_sequence(tmp_path / "s", frames=1, trajectory_seed=2**33), "--trajectory-seed"),
    ]
    for call, option in cases:
        with pytest.raises(ConfigError, match=f"^{option} must be "):
            call()
    assert not any(tmp_path.iterdir())


def test_a_huge_integer_is_refused_not_overflowed() -> None:
    with pytest.raises(ConfigError, match="--stride must be a whole number"):
        limits.check("stride", 10**400)
    assert np.isfinite(limits.check_option("--init-pose", "1 2 0 0 0 0 1")).all()
