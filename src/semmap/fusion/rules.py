"""The label-fusion rules by name (``--fusion``) and their settings; the kernels live one module per family.

============  ==========================================================  =========================  ==============
rule          what a voxel keeps and how a measurement enters             paper                      module
============  ==========================================================  =========================  ==============
``max``       one (label, confidence): the more confident of map and      semantic_slam-style maps   ``max_rule``
              measurement wins; agreeing labels keep the higher one
``topk``      k (label, confidence) pairs + "others" (Algorithm 1)        semantic-octomap, alg. 1   ``topk_bayes``
``bayes``     K log-odds against a pivot class, every pixel adds          semantic-voxel-grid,       ``dense``
              ``l(z) - h0`` (h0 = 0: uniform prior)                       eqs. 2-5
``bayes-prior`` as ``bayes`` but each measurement is divided by the class   rgbd-semantic-mapping,     ``dense``
              prior p(c) (``h0`` = log prior ratios)                      eqs. 3-5
``vote``      K counts of argmax labels                                   (baseline)                 ``dense``
============  ==========================================================  =========================  ==============

A segmenter hands over top-k sets (:class:`~semmap.types.TopKProbs`); the full-K rules read such a set as the
K-vector with the set's probabilities on its classes and the "others" mass ``1 - sum`` spread evenly over the
K - n classes not in the set (n = labels present), every entry raised to at least :data:`MIN_PROB`
(:func:`semmap.fusion.dense.expand_topk`).  A segmenter that hands over k = K gets plain multi-class Bayes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from semmap.errors import ConfigError
from semmap.fusion.topk_bayes import DEFAULT_LAMBDA, DEFAULT_MAX_CONFIDENCE

#: Largest log-odds gap between a voxel's most probable class and any other (the floor of the normalised
#: log-odds): OctoMap-style clamping, so that a voxel stays able to change class after enough contrary
#: evidence (about this many nats).  Eq. 2 sums every pixel of a voxel, each worth 1-2 nats, and a 5 cm voxel
#: 1-1.5 m from a 320x240 camera holds 100-200 pixels a frame: 400 nats kept one or two frames of the near
#: voxels and cost the shipped network 3.9 pixel-MIoU points on a held-out kitchen (bench_fusion); 2000 scores
#: as no clamp at all on the three held-out scenes, never below 400 (docs/EXPERIMENTS.md, "The log-odds floor").
DEFAULT_LOGODDS_CLAMP = 2000.0
#: Weight of the uniform distribution mixed into a ``bayes-prior`` class prior: dividing by a raw frequency
#: lets classes rare in the prior's data win on the spread "others" mass alone (bench_fusion, cnn-like office: raw
#: frequencies 0.12 mIoU, mixed 50 % 0.42, 90 % 0.53, bayes 0.54).
DEFAULT_PRIOR_SMOOTHING = 0.9
#: Vote counts are halved once the largest passes this (keeps float16 counts exact and votes changeable).
DEFAULT_VOTE_CAP = 1024.0


class FusionRule(str, Enum):
    """The built-in rules' names (:mod:`semmap.fusion.registry` holds every rule, these and any registered later)."""

    MAX = "max"
    TOPK = "topk"
    BAYES = "bayes"
    BAYES_PRIOR = "bayes-prior"
    VOTE = "vote"


def fusion_rule(value: str | FusionRule) -> FusionRule | str:
    """``"bayes"`` -> :attr:`FusionRule.BAYES`; a rule registered later -> its name; else a ConfigError listing
    the rules."""
    from semmap.fusion.registry import rule_entry

    name = rule_entry(value).name
    try:
        return FusionRule(name)
    except ValueError:
        return name


@dataclass(frozen=True)
class FusionParams:
    """A fusion rule and its settings.

    ``k`` is the set size of ``topk`` (1..8; ``max`` keeps one pair); ``lam`` and ``max_confidence`` are
    Algorithm 1's penalty and top-confidence cap (``max_confidence`` also caps ``max``); ``logodds_clamp`` is
    the largest log-odds gap ``bayes``/``bayes-prior`` keep; ``prior`` (K,) are the class frequencies
    ``bayes-prior`` divides by (None: uniform, which makes it ``bayes``), mixed with the uniform distribution by
    ``prior_smoothing``.
    """

    rule: FusionRule | str = FusionRule.TOPK
    k: int = 3
    lam: float = DEFAULT_LAMBDA
    max_confidence: float = DEFAULT_MAX_CONFIDENCE
    logodds_clamp: float = DEFAULT_LOGODDS_CLAMP
    vote_cap: float = DEFAULT_VOTE_CAP
    prior: np.ndarray | None = field(default=None, repr=False, compare=False)
    prior_smoothing: float = DEFAULT_PRIOR_SMOOTHING

    def __post_init__(self) -> None:
        object.__setattr__(self, "rule", fusion_rule(self.rule))
        if not 1 <= self.k <= 8:
            raise ConfigError(f"top-k set size must be in 1..8, got {self.k}")
        if not 0.0 <= self.lam <= 1.0:
            raise ConfigError(f"λ must be in [0, 1], got {self.lam}")
        if not 0.0 < self.max_confidence <= 1.0:
            raise ConfigError(f"max_confidence must be in (0, 1], got {self.max_confidence}")
        if not (math.isfinite(self.logodds_clamp) and self.logodds_clamp > 0):
            raise ConfigError(f"log-odds clamp must be positive, got {self.logodds_clamp}")
        if not 2.0 <= self.vote_cap <= 2048.0:
            raise ConfigError(f"vote cap must be in [2, 2048] (float16 counts stay exact), got {self.vote_cap}")
        if not 0.0 <= self.prior_smoothing <= 1.0:
            raise ConfigError(f"prior smoothing must be in [0, 1], got {self.prior_smoothing}")
        if self.prior is not None:
            p = np.asarray(self.prior, np.float64).reshape(-1)
            if p.size < 1 or not np.isfinite(p).all() or (p < 0).any() or p.sum() <= 0:
                raise ConfigError("class prior must be non-negative frequencies with a positive sum")
            object.__setattr__(self, "prior", p)

    @property
    def entry(self):
        """The rule's :class:`~semmap.fusion.registry.RuleEntry` (kernels, state layout)."""
        from semmap.fusion.registry import rule_entry

        return rule_entry(self.rule)

    @property
    def name(self) -> str:
        """The rule's name as ``--fusion`` spells it."""
        return self.entry.name

    def set_width(self) -> int:
        """Pairs kept per voxel by the set rules (0 for the dense ones)."""
        return self.entry.widths(self, 0)[0]

    def kernel_params(self, num_classes: int) -> np.ndarray:
        """The settings as the rule kernels read them (``P_*`` indices of ``fusion.topk_bayes``), then the K prior
        log-odds ``h0`` of the given prior, whichever the rule (float64; zeros without a prior)."""
        head = [self.lam, self.max_confidence, self.logodds_clamp, self.vote_cap]
        return np.concatenate([np.array(head, np.float64),
                               self._mixed_prior_log(max(num_classes, 1)).astype(np.float64)])

    def to_dict(self) -> dict:
        """The settings as a file header stores them (JSON types)."""
        return {"rule": self.name, "k": self.k, "lam": self.lam, "max_confidence": self.max_confidence,
                "logodds_clamp": self.logodds_clamp, "vote_cap": self.vote_cap,
                "prior_smoothing": self.prior_smoothing,
                "prior": None if self.prior is None else [float(v) for v in self.prior]}

    @classmethod
    def from_dict(cls, d: dict) -> FusionParams:
        """Inverse of :meth:`to_dict` (missing settings take their defaults); ConfigError/TypeError when malformed."""
        d = dict(d)
        if d.get("prior") is not None:
            d["prior"] = np.asarray(d["prior"], np.float64)
        return cls(**d)

    def prior_logodds(self, num_classes: int) -> np.ndarray:
        """(K,) float32 ``h0``: log class priors (``bayes-prior``; zeros = uniform otherwise): the frequencies mixed
        with the uniform distribution by ``prior_smoothing``, floored at :data:`~semmap.fusion.dense.MIN_PROB`."""
        if self.rule != FusionRule.BAYES_PRIOR:
            return np.zeros(num_classes, np.float32)
        return self._mixed_prior_log(num_classes)

    def _mixed_prior_log(self, num_classes: int) -> np.ndarray:
        """The given prior's ``h0`` whatever the rule (zeros without a prior): what every rule kernel is handed."""
        from semmap.fusion.dense import MIN_PROB

        if self.prior is None:
            return np.zeros(num_classes, np.float32)
        if self.prior.size != num_classes:
            raise ConfigError(f"class prior has {self.prior.size} entries but the label set {num_classes} classes")
        w = self.prior_smoothing
        p = np.maximum((1.0 - w) * self.prior / self.prior.sum() + w / num_classes, MIN_PROB)
        return np.log(p).astype(np.float32)
