"""Option types and value parsers the command families share: ``--memory-budget``, ``--json``, the
configuration's defaults, ``WxH`` sizes, and validation errors turned into one line naming the option or file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from semmap.config import SemanticSource
from semmap.datasets import AUTO, FORMATS
from semmap.errors import ConfigError, SemmapError

#: ``--memory-budget`` of the commands that allocate in proportion to an option (see ``semmap.limits``).
MemoryBudget = Annotated[str | None, typer.Option(help="refuse options whose memory estimate exceeds this (e.g. "
                                                        "4G; default: SEMMAP_MEMORY_BUDGET, else 75 % of the "
                                                        "available memory)")]


#: ``--json`` of the commands that print a table of their result.
Json = Annotated[bool, typer.Option("--json", help="print the full result as JSON on stdout instead of the table")]


def budget(text: str | None) -> None:
    """Apply ``--memory-budget`` for this command."""
    from semmap.limits import set_memory_budget

    set_memory_budget(text)


def default(section, field: str):
    """The run configuration's default of ``section.field``: the CLI repeats none of them."""
    return section.model_fields[field].default


#: ``--format`` help and ``--semantics`` help, from the registries and the configuration.
FORMATS_HELP = FORMATS.choices((AUTO,))
SOURCES_HELP = " | ".join(s.value for s in SemanticSource)


def parse_color_mode(value: str):
    """``--color-mode`` as the config's enum, or one clear line."""
    from semmap.config import ColorMode

    try:
        return ColorMode(value)
    except ValueError:
        raise SemmapError(f"--color-mode must be one of {[m.value for m in ColorMode]}, got {value!r}") from None


def parse_size(text: str | None) -> tuple[int, int] | int | None:
    """``"512x384"`` -> (512, 384); ``"384"`` -> 384 (the short side)."""
    from semmap.perception.network import parse_input_size

    return parse_input_size(text)


def validated(make, source: Path | None = None):
    """``make()``, its first validation error as one ConfigError line (naming ``source``, the file the values came
    from)."""
    from pydantic import ValidationError

    try:
        return make()
    except SemmapError as exc:  # a limits check inside a validator: say which file the value came from
        if source is None or str(source) in str(exc):
            raise
        raise ConfigError(f"{source}: {exc}") from None
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        msg = str(first["msg"]).removeprefix("Value error, ")
        if source is not None:
            raise ConfigError(f"{source}: {f'field {where}: ' if where else ''}{msg}"
                              f"{'' if where else ' (expected a JSON object like a run folder config.json)'}"
                              ) from None
        if not where:  # a rule across options
            raise ConfigError(msg) from None
        raise ConfigError(f"invalid {option_of(exc.title, first['loc'])}: {msg}") from None


#: configuration fields whose command-line option is not ``--`` + the field's name (section.field -> option)
FIELD_OPTIONS = {
    "semantics.source": "--semantics", "semantics.k": "--top-k", "semantics.lam": "--lambda",
    "poses.source": "--poses", "input.dataset": "dataset argument", "output.out": "--out",
    "crf.enabled": "--crf", "crf.every": "--crf-every", "objects.weights": "--instance-weights",
    "objects.errors": "--instance-errors",
}


def option_of(model_title: str, loc: tuple) -> str:
    """The command-line option a configuration field came from (``SemanticsConfig`` + ``source`` -> ``--semantics``)."""
    from semmap import config as config_module

    model = getattr(config_module, str(model_title), None)
    section = str(getattr(model, "section", "") or "")
    field = str(loc[-1]) if not isinstance(loc[-1], int) else str(loc[-2] if len(loc) > 1 else loc[-1])
    key = f"{section.rsplit('.', 1)[-1]}.{field}" if section else ".".join(str(p) for p in loc)
    return FIELD_OPTIONS.get(key) or f"--{field.replace('_', '-')}"
