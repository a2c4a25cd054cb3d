"""Picture of the object map: every object's points from above in its own colour, its upright box and its id."""

from __future__ import annotations

import cv2
import numpy as np

from semmap.maps.objects import MapObject, upright_box
from semmap.viz.preview import _horizontal_axes

#: Pixels of margin around the objects.
MARGIN = 24


def objects_top_down(objects: list[MapObject], colors: np.ndarray, names: tuple[str, ...], *, up: np.ndarray,
                     size: int = 480, background: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Top-down view (RGB uint8, longest side ``size``): objects' points in ``colors[id - 1]``, their upright box
    outlines and ``id class`` labels; ``background`` (points (M, 3), colours (M, 3)) is drawn dimmed beneath."""
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
        img[q[ok, 1], q[ok, 0]] = (np.asarray(background[1])[ok] * 0.35 + 20).astype(np.uint8)
    for o, p in zip(objects, pts, strict=True):
        q = pix(p)
        ok = (q[:, 0] >= 0) & (q[:, 0] < W) & (q[:, 1] >= 0) & (q[:, 1] < H)
        img[q[ok, 1], q[ok, 0]] = colors[o.id - 1]
    for o, p in zip(objects, pts, strict=True):
        box = upright_box(p, up)
        half = box.extent / 2
        corners = np.array([box.center + box.rotation @ (half * [sx, sy, 0]) for sx, sy in
                            ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        c = tuple(int(x) for x in colors[o.id - 1])
        cv2.polylines(img, [pix(corners).astype(np.int32)], True, c, 1, cv2.LINE_AA)
        at = pix(box.center[None])[0]
        label = f"{o.id} {names[o.class_id]}"
        cv2.putText(img, label, (int(at[0]) - 12, int(at[1]) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 3,
                    cv2.LINE_AA)
        cv2.putText(img, label, (int(at[0]) - 12, int(at[1]) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 255, 255),
                    1, cv2.LINE_AA)
    return img
