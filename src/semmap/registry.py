"""A family of named things (trackers, segmenters, instance sources, maps, dataset formats): one :class:`Registry`
per family is the only list of its names. CLI help, config validation, enums and errors all read it.

Each family has its own entry dataclass holding at least ``name`` and ``help`` (one line), the factory and what
the thing can do (needs depth, needs weights, ...); the registry keeps the entries in order and answers lookups
with one clear line listing the choices.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from enum import Enum, StrEnum
from typing import Protocol, TypeVar

from semmap.errors import ConfigError, SemmapError


class Named(Protocol):
    """What every registry entry has: its name and a one-line help."""

    @property
    def name(self) -> str: ...

    @property
    def help(self) -> str: ...


E = TypeVar("E", bound=Named)


class Registry(Mapping[str, E]):
    """Entries of one family by name, in registration order (the order help texts list them)."""

    def __init__(self, family: str, entries: Iterable[E], error: type[SemmapError] = ConfigError, *,
                 option: str = "") -> None:
        self.family, self.error, self.option = family, error, option
        self._entries: dict[str, E] = {}
        for e in entries:
            if e.name in self._entries:
                raise ValueError(f"{family} {e.name!r} is registered twice")
            self._entries[e.name] = e

    def __getitem__(self, name: str) -> E:
        """The entry ``name``, or the family's error (a ConfigError) listing the choices."""
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            raise self.error(self.unknown(name)) from None

    def __contains__(self, name: object) -> bool:
        try:
            return name in self._entries
        except TypeError:  # unhashable
            return False

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def names(self) -> tuple[str, ...]:
        """The names, in order."""
        return tuple(self._entries)

    def where(self, **caps: object) -> tuple[str, ...]:
        """Names of the entries whose attributes equal ``caps`` (e.g. ``where(needs_weights=True)``)."""
        return tuple(n for n, e in self._entries.items() if all(getattr(e, k) == v for k, v in caps.items()))

    def choices(self, extra: Iterable[str] = (), sep: str = " | ") -> str:
        """``"a | b | c"`` for help texts (``extra`` names first, e.g. ``auto``)."""
        return sep.join((*extra, *self._entries))

    def unknown(self, name: object, extra: Iterable[str] = ()) -> str:
        """The one-line error for a name that is not registered (naming the option that takes it, if one does)."""
        where = f"{self.option}: " if self.option else ""
        return f"{where}unknown {self.family} {name!r}; choose from {self.choices(extra, ', ')}"

    def describe(self) -> str:
        """One ``name: help`` line per entry (for ``--help`` epilogues and docs)."""
        return "\n".join(f"{n}: {e.help}" for n, e in self._entries.items())

    def enum(self, cls_name: str, module: str, extra: Iterable[str] = (), *, str_mixin: bool = False) -> type[Enum]:
        """An Enum of the names (``extra`` first) for typed config fields: a ``StrEnum`` (``str_mixin``: a
        ``(str, Enum)``, whose ``str()`` is ``Class.MEMBER``). ``module`` is where it is bound, so it pickles."""
        return name_enum(cls_name, module, (*extra, *self._entries), str_mixin=str_mixin)


def name_enum(cls_name: str, module: str, names: Iterable[str], *, str_mixin: bool = False) -> type[Enum]:
    """An Enum whose values are ``names`` (see :meth:`Registry.enum`)."""
    members = [(_member_name(n), n) for n in names]
    if str_mixin:
        return Enum(cls_name, members, type=str, module=module)
    return StrEnum(cls_name, members, module=module)


def _member_name(name: str) -> str:
    """``"bayes-prior"`` -> ``BAYES_PRIOR``; a leading digit gets an underscore (``"7scenes"`` -> ``_7SCENES``)."""
    member = name.upper().replace("-", "_")
    return f"_{member}" if member[:1].isdigit() else member


def check_name(registry: Registry, value: object, extra: Iterable[str] = ()) -> object:
    """For pydantic ``mode="before"`` validators: ``value`` unchanged when it is a registered name (or ``extra``,
    or None), else a ValueError with the registry's one-line message."""
    extra = tuple(extra)
    if value is None or value in registry or value in extra:
        return value
    raise ValueError(registry.unknown(value, extra))
