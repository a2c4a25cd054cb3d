"""Numba kernels that turn low-resolution network logits into full-resolution top-k class probabilities.

Softmax runs on the network's grid (a few times fewer pixels than the image), then each image pixel blends
the four surrounding probability vectors bilinearly and keeps its k largest entries.  Blending probabilities
rather than logits keeps every pixel a proper distribution, and one fused pass avoids materialising the
(H, W, K) float tensor that dominated the frame time when done with torch.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(parallel=True, cache=True, nogil=True)
def softmax_channels_last(logits: np.ndarray) -> np.ndarray:
    """(h, w, K) float32 probabilities from (K, h, w) float32 logits (max-subtracted, so large logits are safe)."""
    n_classes, h, w = logits.shape
    out = np.empty((h, w, n_classes), np.float32)
    for y in nb.prange(h):
        for x in range(w):
            m = logits[0, y, x]
            for c in range(1, n_classes):
                m = max(m, logits[c, y, x])
            total = 0.0
            for c in range(n_classes):
                e = np.exp(logits[c, y, x] - m)
                out[y, x, c] = e
                total += e
            inv = 1.0 / total
            for c in range(n_classes):
                out[y, x, c] *= inv
    return out


@nb.njit(cache=True, nogil=True)
def _taps(n_out: int, n_src: int, scale: float, offset: float):
    """For each output index i, the two source indices and the weight of the second for s = scale*i + offset,
    clamped to the source grid (the border pixels repeat, as in torch and OpenCV)."""
    i0 = np.empty(n_out, np.int64)
    i1 = np.empty(n_out, np.int64)
    frac = np.empty(n_out, np.float32)
    for i in range(n_out):
        s = min(max(scale * i + offset, 0.0), n_src - 1.0)
        a = min(int(s), n_src - 1)
        i0[i] = a
        i1[i] = min(a + 1, n_src - 1)
        frac[i] = s - a
    return i0, i1, frac


@nb.njit(parallel=True, cache=True, nogil=True)
def resample_topk(probs: np.ndarray, out_h: int, out_w: int, sy: float, oy: float, sx: float, ox: float,
                  k: int, empty_label: int):
    """Bilinearly sample (h, w, K) ``probs`` at rows ``sy*y + oy`` and columns ``sx*x + ox`` of an
    ``out_h`` x ``out_w`` image and keep the top ``k`` classes per pixel, sorted descending.

    Returns labels (out_h, out_w, k) uint16 and probabilities (out_h, out_w, k) float32; slots beyond the
    number of classes hold ``empty_label`` and 0.
    """
    h, w, n_classes = probs.shape
    y0, y1, fy = _taps(out_h, h, sy, oy)
    x0, x1, fx = _taps(out_w, w, sx, ox)
    labels = np.full((out_h, out_w, k), empty_label, np.uint16)
    top = np.zeros((out_h, out_w, k), np.float32)
    kk = min(k, n_classes)
    for y in nb.prange(out_h):
        v = np.empty(n_classes, np.float32)
        ay, by = 1.0 - fy[y], fy[y]
        r0, r1 = y0[y], y1[y]
        for x in range(out_w):
            ax, bx = 1.0 - fx[x], fx[x]
            c0, c1 = x0[x], x1[x]
            w00, w01, w10, w11 = ay * ax, ay * bx, by * ax, by * bx
            for c in range(n_classes):
                v[c] = (w00 * probs[r0, c0, c] + w01 * probs[r0, c1, c]
                        + w10 * probs[r1, c0, c] + w11 * probs[r1, c1, c])
            for j in range(kk):
                best = 0
                best_v = v[0]
                for c in range(1, n_classes):
                    if v[c] > best_v:
                        best_v = v[c]
                        best = c
                labels[y, x, j] = best
                top[y, x, j] = best_v
                v[best] = -1.0
    return labels, top


def sampling_map(n_out: int, n_in: int, n_logit: int, logits_align_corners: bool) -> tuple[float, float]:
    """(scale, offset) mapping an image index to a logit-grid coordinate.

    The image (``n_out`` pixels) was resized to the network input (``n_in``) with half-pixel centres
    (OpenCV ``INTER_LINEAR``); the network's ``n_logit`` outputs span that input either corner to corner
    (``align_corners=True``) or with half-pixel centres.
    """
    a, b = n_in / n_out, 0.5 * n_in / n_out - 0.5  # image index -> input coordinate
    if logits_align_corners:
        c, d = (n_logit - 1) / max(n_in - 1, 1), 0.0
    else:
        c, d = n_logit / n_in, 0.5 * n_logit / n_in - 0.5
    return a * c, b * c + d
