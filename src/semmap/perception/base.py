"""The segmenter interface: a frame in, per-pixel class probabilities (top-k) out."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from semmap.types import Frame, LabelSet, TopKProbs


@runtime_checkable
class Segmenter(Protocol):
    """Anything that turns a frame into per-pixel class probabilities over its ``label_set``."""

    #: Short name used in reports (e.g. ``oracle`` gives ``oracle_miou_2d``).
    name: str

    @property
    def label_set(self) -> LabelSet: ...

    def segment(self, frame: Frame) -> TopKProbs:
        """(H, W, k) top-k class distribution for ``frame`` (k = 3 unless configured otherwise)."""
        ...


@runtime_checkable
class Preparable(Protocol):
    """A segmenter with a one-off start-up cost (an ONNX export, a runtime session, kernel selection) that a run
    pays before its frame loop, so per-frame timings and latencies show what every frame costs."""

    def prepare(self, frame: Frame) -> float:
        """Get ready for frames like ``frame``; returns the seconds it took."""
        ...
