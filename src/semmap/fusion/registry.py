"""The fusion rules by name: one entry per rule (its numba kernels, state layout and width), the only list of them.

A rule is one module in ``fusion/`` with an ``update`` kernel (and optionally a ``finish`` kernel) of the
dispatcher's signatures (:data:`~semmap.fusion.dispatch.UPDATE_SIG`, :data:`~semmap.fusion.dispatch.FINISH_SIG`),
plus one :func:`register` line below; every map (OctoMap, voxel grid, point map) then fuses with it, stores it,
coarsens it, writes it to its native file and reads it back.  A rule registered from elsewhere (a test, a user's
script) works the same way, through the dispatcher's generic path.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

import numba as nb
import numpy as np

from semmap.errors import ConfigError
from semmap.fusion import dispatch as dp
from semmap.fusion.dense import (
    bayes_finish,
    bayes_fuse,
    bayes_prior_finish,
    expand_topk,
    logodds_to_probs,
    vote_finish,
    vote_fuse,
    votes_to_probs,
)
from semmap.fusion.max_rule import max_fuse
from semmap.fusion.rules import FusionParams, FusionRule
from semmap.fusion.topk_bayes import MAX_SET, topk_fuse
from semmap.types import EMPTY_LABEL, TopKProbs

#: State layouts by name (see :mod:`semmap.fusion.dispatch`).
LAYOUTS = {"set": dp.LAYOUT_SET, "logodds": dp.LAYOUT_LOGODDS, "counts": dp.LAYOUT_COUNTS}


def _one_pair(params: FusionParams) -> int:
    return 1


@dataclass(frozen=True)
class RuleEntry:
    """One fusion rule: ``name`` (``--fusion``), a one-line ``help``, its state ``layout`` (``set``, ``logodds`` or
    ``counts``), its ``update`` / ``finish`` kernels (numba-compilable, dispatcher signatures; ``finish`` None: no
    step after a frame), ``set_width`` (pairs a ``set`` voxel keeps), ``sets_of_k`` (measurements must hold exactly
    ``k`` pairs) and ``code``, the dispatcher's inlined fast path of a built-in rule (``GENERIC`` otherwise)."""

    name: str
    help: str
    layout: str
    update: Callable
    finish: Callable | None = None
    set_width: Callable[[FusionParams], int] = _one_pair
    sets_of_k: bool = False
    code: int = dp.GENERIC

    @property
    def layout_code(self) -> int:
        return LAYOUTS[self.layout]

    @property
    def dense(self) -> bool:
        """True for the rules that keep K numbers per voxel."""
        return self.layout != "set"

    def widths(self, params: FusionParams, num_classes: int) -> tuple[int, int]:
        """(S labels, W values) per voxel: S = W pairs for a set rule, (0, K) for a dense one."""
        if self.dense:
            return 0, num_classes
        s = int(self.set_width(params))
        if not 1 <= s <= MAX_SET:
            raise ConfigError(f"fusion rule {self.name!r} keeps {s} pairs per voxel; allowed 1..{MAX_SET}")
        return s, s

    def kernels(self) -> tuple:
        """The compiled (update, finish) the map kernels take as first-class function values (built on first use)."""
        got = _COMPILED.get(self.name)
        if got is None or got[0] is not self:
            upd = nb.cfunc(dp.UPDATE_SIG, cache=True)(getattr(self.update, "py_func", self.update))
            fin = (_no_finish() if self.finish is None
                   else nb.cfunc(dp.FINISH_SIG, cache=True)(getattr(self.finish, "py_func", self.finish)))
            got = _COMPILED[self.name] = (self, upd, fin)
        return got[1], got[2]

    # ------------------------------------------------------------------ the state read and written from Python
    def class_probs(self, labels: np.ndarray, values: np.ndarray, num_classes: int) -> np.ndarray:
        """(M, K) class distribution of (M, S) labels and (M, W) float values (a set read as a K-vector with
        "others" spread over the classes outside it)."""
        if self.layout == "logodds":
            return logodds_to_probs(values).astype(np.float32)
        if self.layout == "counts":
            return votes_to_probs(values).astype(np.float32)
        p = expand_topk(labels, values, num_classes)
        return (p / p.sum(1, keepdims=True)).astype(np.float32)

    def top(self, labels: np.ndarray, values: np.ndarray, num_classes: int) -> tuple[np.ndarray, np.ndarray]:
        """Most probable class (EMPTY where there is no evidence) and its probability, per row."""
        m = values.shape[0]
        if not self.dense:
            if labels.shape[1] == 0:
                return np.full(m, EMPTY_LABEL, np.uint16), np.zeros(m, np.float32)
            return labels[:, 0].copy(), values[:, 0].astype(np.float32)
        lab = np.full(m, EMPTY_LABEL, np.uint16)
        conf = np.zeros(m, np.float32)
        has = (values != 0).any(1) if values.shape[1] else np.zeros(m, bool)
        if has.any():
            p = self.class_probs(labels[has], values[has], num_classes)
            lab[has] = p.argmax(1)
            conf[has] = p.max(1)
        return lab, conf

    def sets(self, labels: np.ndarray, values: np.ndarray, num_classes: int, k: int) -> TopKProbs:
        """Each row's state as a top-k set (a set rule's own pairs; a dense rule's k most probable classes)."""
        if not self.dense:
            return TopKProbs(labels.copy(), values.astype(np.float32))
        out = TopKProbs(np.full((values.shape[0], k), EMPTY_LABEL, np.uint16), np.zeros((values.shape[0], k),
                                                                                          np.float32))
        has = (values != 0).any(1) if values.shape[1] else np.zeros(values.shape[0], bool)
        if has.any():
            top = TopKProbs.from_dense(self.class_probs(labels[has], values[has], num_classes), k)
            out.labels[has], out.probs[has] = top.labels, top.probs
        return out

    def from_probs(self, probs: np.ndarray, params: FusionParams) -> tuple[np.ndarray, np.ndarray]:
        """(labels, float values) of the state that holds the (M, K) distributions ``probs`` (e.g. a CRF's
        posterior): log-odds, vote shares scaled to the cap, or the top pairs (top confidence capped)."""
        p = np.clip(np.asarray(probs, np.float64), 1e-12, None)
        p /= p.sum(1, keepdims=True)
        empty = np.zeros((p.shape[0], 0), np.uint16)
        if self.layout == "counts":
            return empty, np.floor(p / p.max(1, keepdims=True) * params.vote_cap * 0.5).astype(np.float32)
        if self.layout == "logodds":
            h = np.log(p)
            return empty, np.maximum(h - h.max(1, keepdims=True), -params.logodds_clamp).astype(np.float32)
        top = TopKProbs.from_dense(p, self.widths(params, p.shape[1])[0])
        return top.labels, np.minimum(top.probs, params.max_confidence).astype(np.float32)


_RULES: dict[str, RuleEntry] = {}
_COMPILED: dict[str, tuple] = {}
_NO_FINISH: list = []


def _no_finish():
    if not _NO_FINISH:
        _NO_FINISH.append(nb.cfunc(dp.FINISH_SIG, cache=True)(_noop_finish))
    return _NO_FINISH[0]


def _noop_finish(labels: np.ndarray, values: np.ndarray, n: int, params: np.ndarray) -> None:
    return None


def register(entry: RuleEntry, *, replace: bool = False) -> RuleEntry:
    """Add a rule (``replace``: let it take an existing name's place); returns it."""
    name = entry.name.value if isinstance(entry.name, Enum) else str(entry.name)
    if entry.layout not in LAYOUTS:
        raise ConfigError(f"fusion rule {name!r}: layout must be one of {', '.join(LAYOUTS)}, got {entry.layout!r}")
    if name in _RULES and not replace:
        raise ConfigError(f"a fusion rule named {name!r} is already registered")
    if entry.code != dp.GENERIC and name not in {r.value for r in FusionRule}:
        raise ConfigError(f"fusion rule {name!r}: only the built-in rules have a dispatcher fast path")
    entry = RuleEntry(name, entry.help, entry.layout, entry.update, entry.finish, entry.set_width, entry.sets_of_k,
                      entry.code)
    _RULES[name] = entry
    _COMPILED.pop(name, None)
    return entry


def unregister(name: str) -> None:
    """Remove a rule registered with :func:`register` (not a built-in one)."""
    if name in {r.value for r in FusionRule}:
        raise ConfigError(f"{name!r} is a built-in fusion rule")
    _RULES.pop(name, None)
    _COMPILED.pop(name, None)


def rule_names() -> tuple[str, ...]:
    """Every registered rule's name, built-in ones first."""
    return tuple(_RULES)


def rule_entry(name: str | FusionRule) -> RuleEntry:
    """The entry of a rule, or a ConfigError listing the rules."""
    key = name.value if isinstance(name, Enum) else name
    try:
        return _RULES[key]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown fusion rule {name!r}; choose from {', '.join(_RULES)}") from None


# ---------------------------------------------------------------------------------------------- the rules
register(RuleEntry(FusionRule.MAX, "one (label, confidence): the more confident of voxel and measurement wins",
                   "set", max_fuse, code=dp.MAX_CODE))
register(RuleEntry(FusionRule.TOPK, "k (label, confidence) pairs + others (semantic OctoMap, Algorithm 1)",
                   "set", topk_fuse, set_width=lambda p: p.k, sets_of_k=True, code=dp.TOPK_CODE))
register(RuleEntry(FusionRule.BAYES, "K log-odds, recursive multi-class Bayes", "logodds", bayes_fuse,
                   bayes_finish, code=dp.BAYES_CODE))
register(RuleEntry(FusionRule.BAYES_PRIOR, "K log-odds, Bayes with each measurement divided by the class prior",
                   "logodds", bayes_fuse, bayes_prior_finish, code=dp.BAYES_PRIOR_CODE))
register(RuleEntry(FusionRule.VOTE, "K counts of argmax labels", "counts", vote_fuse, vote_finish,
                   code=dp.VOTE_CODE))
