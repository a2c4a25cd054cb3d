"""Parsing the text fields of handed-over files."""

from __future__ import annotations


def is_number(text: str) -> bool:
    """Whether ``float(text)`` accepts ``text`` (a timestamp, a pose value, a frame name made of a number)."""
    try:
        float(text)
    except ValueError:
        return False
    return True
