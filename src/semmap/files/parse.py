"""Parsing the text fields of handed-over files, and JSON that any reader can parse back."""

from __future__ import annotations

import math


def is_number(text: str) -> bool:
    """Whether ``float(text)`` accepts ``text`` (a timestamp, a pose value, a frame name made of a number)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def json_safe(value: object) -> object:
    """``value`` with every NaN or infinite float (also inside dicts, lists and tuples) as None: standard JSON has no
    ``NaN`` / ``Infinity``, so a score that could not be computed is written as ``null``."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value
