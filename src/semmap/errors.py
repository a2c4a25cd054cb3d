"""Exception hierarchy: the library raises these, the CLI turns them into one clear line."""

from __future__ import annotations


class SemmapError(Exception):
    """Root of every error semmap raises on purpose (bad input, bad files, bad settings)."""


class DatasetError(SemmapError):
    """A dataset folder or one of its files is missing, malformed or inconsistent."""


class FormatError(SemmapError):
    """A map file (.bt, .ot, .semmap) is truncated, malformed or of the wrong kind."""


class ConfigError(SemmapError):
    """An option or a combination of options makes no sense."""


class SimulationError(SemmapError):
    """The scene generator or renderer was asked for something it cannot do."""


class OutputError(SemmapError):
    """An output cannot be written where asked: it would replace an input, is not a regular file or folder, or its
    name or disk refuses it."""
