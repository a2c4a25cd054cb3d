"""Picture of the object map: every object's points from above in its own colour, its upright box and its id."""

from __future__ import annotations

import cv2
import numpy as np

from semmap.maps.objects import MapObject, upright_box
from semmap.viz.preview import _horizontal_axes

#: Pixels of margin around the objects.
MARGIN = 24
#: Most ``id class`` labels one picture draws (the largest objects first).
MAX_LABELS = 30
#: Pixels kept free around each label: a label that would come closer to another is left out.
LABEL_GAP = 2
FONT, FONT_SCALE = cv2.FONT_HERSHEY_SIMPLEX, 0.38
#: Share of its own colour a background voxel keeps (dimmed beneath the objects, still readable).
BACKGROUND_DIM = 0.55


def objects_top_down(objects: list[MapObject], colors: np.ndarray, names: tuple[str, ...], *, up: np.ndarray,
                     size: int = 480, background: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Top-down view (RGB uint8, longest side ``size``): objects' points in ``colors[id - 1]``, their upright box
    outlines and ``id class`` labels where they do not overprint (:func:`readable_labels`); ``background``
    (points (M, 3), colours (M, 3)) is drawn dimmed beneath."""
    e1, e2 = _horizontal_axes(up)
    pts = [o.points.astype(np.float64) for o in objects]
    every = np.concatenate(pts + ([background[0]] if background is not None else [])) if pts or background else \
        np.zeros((0, 3))
    if len(every) == 0:
        return np.full((64, 64, 3), 32, np.uint8)
    u_all, v_all = every @ e1, every @ e2
    lo = np.array([u_all.min(), v_all.min()])
    span = max(u_all.max() - lo[0], v_all.max() - lo[1], 1e-3)
    scale = (size - 2 * MARGIN) / span
    W = int((u_all.max() - lo[0]) * scale) + 2 * MARGIN
    H = int((v_all.max() - lo[1]) * scale) + 2 * MARGIN
    img = np.full((H, W, 3), 32, np.uint8)

    def pix(p: np.ndarray) -> np.ndarray:
        u = (p @ e1 - lo[0]) * scale + MARGIN
        v = H - ((p @ e2 - lo[1]) * scale + MARGIN)
        return np.column_stack([u, v]).round().astype(np.int64)

    if background is not None and len(background[0]):
        q = pix(np.asarray(background[0], np.float64))
        ok = (q[:, 0] >= 0) & (q[:, 0] < W) & (q[:, 1] >= 0) & (q[:, 1] < H)
        img[q[ok, 1], q[ok, 0]] = (np.asarray(background[1])[ok] * BACKGROUND_DIM + 20).astype(np.uint8)
    for o, p in zip(objects, pts, strict=True):
        q = pix(p)
        ok = (q[:, 0] >= 0) & (q[:, 0] < W) & (q[:, 1] >= 0) & (q[:, 1] < H)
        img[q[ok, 1], q[ok, 0]] = colors[o.id - 1]
    anchors = []
    for o, p in zip(objects, pts, strict=True):
        box = upright_box(p, up)
        half = box.extent / 2
        corners = np.array([box.center + box.rotation @ (half * [sx, sy, 0]) for sx, sy in
                            ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        cv2.polylines(img, [pix(corners).astype(np.int32)], True, tuple(int(x) for x in colors[o.id - 1]), 1,
                      cv2.LINE_AA)
        anchors.append(pix(box.center[None])[0])
    labels = [f"{o.id} {names[o.class_id]}" for o in objects]
    chosen = readable_labels(labels, anchors, [len(o) for o in objects], (W, H))
    for i, (x, y) in chosen.items():
        _text(img, labels[i], (x, y), (255, 255, 255))
    if len(chosen) < len(objects):
        _text(img, f"{len(objects) - len(chosen)} overlapping labels left out (all in objects.json)", (4, H - 6),
              (200, 200, 200))
    return img


def _text(img: np.ndarray, text: str, at: tuple[int, int], color: tuple[int, int, int]) -> None:
    """``text`` at ``at`` (its baseline's start), outlined in black so that it reads on any colour."""
    cv2.putText(img, text, at, FONT, FONT_SCALE, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, at, FONT, FONT_SCALE, color, 1, cv2.LINE_AA)


def readable_labels(labels: list[str], anchors: list[np.ndarray], sizes: list[int], image_size: tuple[int, int], *,
                    max_labels: int = MAX_LABELS) -> dict[int, tuple[int, int]]:
    """Which labels to draw and where (index -> baseline start): the largest objects first, each centred on its
    anchor and kept only where it overprints no label already kept (a shelf of books gets one or two, not forty),
    at most ``max_labels``."""
    W, H = image_size
    kept: dict[int, tuple[int, int]] = {}
    boxes: list[tuple[int, int, int, int]] = []
    for i in sorted(range(len(labels)), key=lambda j: -sizes[j]):
        if len(kept) >= max_labels:
            break
        (tw, th), base = cv2.getTextSize(labels[i], FONT, FONT_SCALE, 3)
        x = int(np.clip(anchors[i][0] - tw // 2, 0, max(W - tw, 0)))
        y = int(np.clip(anchors[i][1] + th // 2, th, H - base))
        box = (x - LABEL_GAP, y - th - LABEL_GAP, x + tw + LABEL_GAP, y + base + LABEL_GAP)
        if any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in boxes):
            continue
        kept[i] = (x, y)
        boxes.append(box)
    return kept
