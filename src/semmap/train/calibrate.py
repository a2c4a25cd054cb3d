"""Fitting the temperature of a network's probabilities on validation images, and the two scores that say how
well calibrated they are: negative log-likelihood (NLL, nats per pixel) and expected calibration error (ECE,
15 equal-width confidence bins, Guo et al. 2017).

The fit minimises the NLL over log T by golden-section search on [log 0.05, log 20]: one parameter and a
convex objective in 1/T, so a 1-D search finds the optimum without any learning rate or stopping rule."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

#: Confidence bins of the expected calibration error.
ECE_BINS = 15
#: Search interval of the temperature.
T_MIN, T_MAX = 0.05, 20.0
#: Golden-section steps (the interval shrinks by 0.618 each: 60 steps leave 1e-12 of log T).
SEARCH_STEPS = 60


def _log_softmax(logits: np.ndarray) -> np.ndarray:
    z = logits - logits.max(axis=1, keepdims=True)
    return z - np.log(np.exp(z).sum(axis=1, keepdims=True))


def nll(logits: np.ndarray, labels: np.ndarray, temperature: float = 1.0) -> float:
    """Mean negative log-likelihood of ``labels`` (N,) under ``softmax(logits / T)`` (logits (N, K))."""
    lp = _log_softmax(np.asarray(logits, np.float64) / temperature)
    return float(-lp[np.arange(len(labels)), labels].mean())


def fit_temperature(logits: np.ndarray, labels: np.ndarray) -> float:
    """The temperature T minimising :func:`nll` of ``labels`` (N,) under ``softmax(logits / T)``."""
    logits = np.asarray(logits, np.float64)
    labels = np.asarray(labels, np.int64)
    if len(labels) == 0:
        raise ValueError("no labelled pixels to fit a temperature on")
    lo, hi = math.log(T_MIN), math.log(T_MAX)
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    fa, fb = nll(logits, labels, math.exp(a)), nll(logits, labels, math.exp(b))
    for _ in range(SEARCH_STEPS):
        if fa <= fb:
            hi, b, fb = b, a, fa
            a = hi - g * (hi - lo)
            fa = nll(logits, labels, math.exp(a))
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = nll(logits, labels, math.exp(b))
    return float(math.exp((lo + hi) / 2.0))


def expected_calibration_error(confidence: np.ndarray, correct: np.ndarray, bins: int = ECE_BINS) -> float:
    """ECE: the pixel-weighted mean gap |accuracy - mean confidence| over ``bins`` equal-width confidence bins
    (``confidence``: the top class's probability, ``correct``: whether the top class is right)."""
    confidence = np.asarray(confidence, np.float64).ravel()
    correct = np.asarray(correct, np.float64).ravel()
    if confidence.size == 0:
        return float("nan")
    idx = np.clip((confidence * bins).astype(np.int64), 0, bins - 1)
    count = np.bincount(idx, minlength=bins)
    gap = np.abs(np.bincount(idx, correct, bins) - np.bincount(idx, confidence, bins))
    return float(gap.sum() / count.sum())


def calibration_scores(probabilities: np.ndarray, labels: np.ndarray) -> dict:
    """{"ece", "nll"} of probabilities (N, K) for ``labels`` (N,)."""
    p = np.asarray(probabilities, np.float64)
    labels = np.asarray(labels, np.int64)
    top = p.argmax(axis=1)
    conf = p[np.arange(len(labels)), top]
    p_true = np.clip(p[np.arange(len(labels)), labels], 1e-12, 1.0)
    return {"ece": round(expected_calibration_error(conf, top == labels), 4),
            "nll": round(float(-np.log(p_true).mean()), 4)}


def calibrate_weights(weights: Path, val: list[Path], out: Path, *, pixel_step: int = 8) -> dict:
    """Fit the temperature of the network in ``weights`` on the validation folders ``val`` (at its training size,
    every ``pixel_step``-th row and column, void left out) and write a copy of the file to ``out`` with
    ``meta.temperature`` and ``meta.calibration`` (NLL and ECE before and after); returns that record."""
    from semmap.files.outputs import OutputKind, check_outputs
    from semmap.perception.networks.registry import load_weights
    from semmap.train.class_weights import IGNORE
    from semmap.train.data import gather

    check_outputs([("--out", out, OutputKind.FILE)], [("--weights", weights), *(("--val", v) for v in val)])
    net = load_weights(weights)
    ds = gather(list(val), net.input_size, label_set=net.label_set, need_depth=net.spec.uses_depth)
    k = len(net.label_set)
    logits, labels = [], []
    for i, lg in image_logits(net, ds, range(len(ds))):
        logits.append(lg[:, :, ::pixel_step, ::pixel_step].permute(0, 2, 3, 1).reshape(-1, k).numpy())
        labels.append(ds.labels[i, ::pixel_step, ::pixel_step].reshape(-1).astype(np.int64))
    z, y = np.concatenate(logits), np.concatenate(labels)
    keep = y != IGNORE
    z, y = z[keep], y[keep]
    record = fitted_record(z, y) | {"images": len(ds)}
    write_calibrated(net, out, record)
    return record


def fitted_record(logits: np.ndarray, labels: np.ndarray) -> dict:
    """The NLL temperature of (N, K) ``logits`` (log-probabilities will do) against ``labels``, with NLL and ECE
    before and after: the ``meta.calibration`` record a calibrated weight file carries."""
    t = fit_temperature(logits, labels)
    before, after = calibration_scores(softmax(logits), labels), calibration_scores(softmax(logits / t), labels)
    return {"temperature": round(t, 4), "pixels": len(labels), "nll": before["nll"], "nll_calibrated": after["nll"],
            "ece": before["ece"], "ece_calibrated": after["ece"]}


def write_calibrated(net, out: Path, record: dict) -> None:
    """A copy of the loaded weight file ``net`` at ``out`` carrying ``record``'s temperature and the record."""
    from semmap.perception.networks.registry import save_weights

    meta = dict(net.meta) | {"temperature": record["temperature"], "calibration": record}
    save_weights(out, net.model, net.spec, net.label_set, net.input_size, meta)


def softmax(logits: np.ndarray) -> np.ndarray:
    """Row-wise softmax of (N, K) logits."""
    z = np.exp(logits - logits.max(axis=1, keepdims=True))
    return z / z.sum(axis=1, keepdims=True)


def image_logits(net, ds, indices):
    """(index, logits (1, K, H, W) at the training size) of each image ``indices`` of training set ``ds`` under a
    loaded weight file ``net``, normalised and with depth as the trainer feeds them, without gradients."""
    import torch

    from semmap.perception.network import IMAGENET_MEAN, IMAGENET_STD
    from semmap.train.data import DEPTH_MM

    mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
    net.model.eval()
    with torch.no_grad():
        for i in indices:
            rgb = torch.from_numpy(ds.rgb[i : i + 1]).permute(0, 3, 1, 2).float().div_(255.0)
            depth = None if ds.depth is None else torch.from_numpy(ds.depth[i : i + 1] / DEPTH_MM).float()[:, None]
            yield i, net.model.forward_train((rgb - mean) / std, depth)[0]
