"""Preview images of a map: a top-down orthographic view (class colours and RGB side by side)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numba as nb
import numpy as np

from semmap.errors import SemmapError
from semmap.files.atomic import write_bytes_atomic
from semmap.types import LabelSet, MapCloud, muted_grey

#: Voxels higher than the highest camera by more than this are cut away (ceilings, top cabinets).
CEILING_MARGIN = 0.6
#: Most classes a picture's legend names, the most frequent first (the rest are counted as "+N more").
LEGEND_MAX_CLASSES = 16


def up_vector(poses: list[np.ndarray] | np.ndarray) -> np.ndarray:
    """World "up" estimated from camera poses: hand-held cameras are held roughly upright, so the mean of
    the cameras' -y axes (image up) points against gravity.  Falls back to +z."""
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    if len(poses) == 0:
        return np.array([0.0, 0.0, 1.0])
    up = -poses[:, :3, 1].mean(axis=0)
    n = np.linalg.norm(up)
    if n < 0.3:
        return np.array([0.0, 0.0, 1.0])
    up /= n
    # snap to a world axis when nearly aligned (simulators and most datasets use z-up or y-up)
    axis = np.argmax(np.abs(up))
    if abs(up[axis]) > 0.9:
        snapped = np.zeros(3)
        snapped[axis] = np.sign(up[axis])
        return snapped
    return up


def _horizontal_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ref = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - up * (ref @ up)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


def top_down(centers: np.ndarray, colors: np.ndarray, resolution: float, *, up: np.ndarray,
             max_height: float | None = None, size: int = 480) -> np.ndarray:
    """Orthographic view from above: each pixel shows the highest voxel below ``max_height`` (heights along
    ``up``), shaded by height; returns an RGB uint8 image (dark background where nothing is mapped)."""
    if len(centers) == 0:
        return np.full((64, 64, 3), 32, np.uint8)
    e1, e2 = _horizontal_axes(up)
    h = centers @ up
    keep = h <= max_height if max_height is not None else np.ones(len(h), bool)
    if not keep.any():
        keep[:] = True
    c, col, h = centers[keep], colors[keep], h[keep]
    u, v = c @ e1, c @ e2
    px = resolution * 0.75  # each voxel is splatted as 2x2 pixels: no gaps when the axes are tilted
    iu = ((u - u.min()) / px).astype(np.int64)
    iv = ((v.max() - v) / px).astype(np.int64)
    H, W = iv.max() + 2, iu.max() + 2
    order = np.argsort(h, kind="stable")  # later (higher) voxels overwrite lower ones
    img = np.full((H, W, 3), 32, np.uint8)
    span = max(h.max() - h.min(), 1e-6)
    shade = 0.55 + 0.45 * (h - h.min()) / span
    shaded = np.clip(col[order] * shade[order, None], 0, 255).astype(np.uint8)
    rows = np.stack([iv[order], iv[order] + 1], 1)
    cols = np.stack([iu[order], iu[order] + 1], 1)
    for dy in (0, 1):  # a pixel keeps the highest voxel among those splatted onto it
        for dx in (0, 1):
            img[rows[:, dy], cols[:, dx]] = shaded
    scale = size / max(H, W)  # one voxel -> a block of pixels, longest side ``size``
    return cv2.resize(img, (max(1, round(W * scale)), max(1, round(H * scale))), interpolation=cv2.INTER_NEAREST)


@nb.njit(cache=True)
def _splat(img, zbuf, u, v, z, size, colors):
    H, W = zbuf.shape
    for i in range(u.shape[0]):
        h = size[i] // 2
        for y in range(max(0, v[i] - h), min(H, v[i] - h + size[i])):
            for x in range(max(0, u[i] - h), min(W, u[i] - h + size[i])):
                if z[i] < zbuf[y, x]:
                    zbuf[y, x] = z[i]
                    img[y, x, 0] = colors[i, 0]
                    img[y, x, 1] = colors[i, 1]
                    img[y, x, 2] = colors[i, 2]


def perspective(centers: np.ndarray, colors: np.ndarray, resolution: float, *, up: np.ndarray,
                width: int = 640, height: int = 480, max_height: float | None = None,
                azimuth_deg: float = 0.0, tilt_deg: float = 40.0) -> np.ndarray:
    """Voxels seen from above one corner of the map (a pinhole camera looking down at ``tilt_deg``, turned by
    ``azimuth_deg`` about the up axis), drawn as z-buffered squares with simple depth shading; returns an RGB
    uint8 image."""
    img = np.full((height, width, 3), 32, np.uint8)
    if len(centers) == 0:
        return img
    h = centers @ up
    keep = h <= max_height if max_height is not None else np.ones(len(h), bool)
    c, col = centers[keep], colors[keep]
    if len(c) == 0:
        return img
    e1, e2 = _horizontal_axes(up)
    mid = (c.min(axis=0) + c.max(axis=0)) / 2
    radius = max(float(np.linalg.norm(c.max(axis=0) - c.min(axis=0))) / 2, resolution * 4)
    tilt = np.deg2rad(tilt_deg)
    az = np.deg2rad(azimuth_deg)
    back = -(0.8 * e1 + 0.6 * e2)
    back = np.cos(az) * back + np.sin(az) * np.cross(up, back)  # rotate about up (back is horizontal)
    fwd = np.cos(tilt) * -back - np.sin(tilt) * up
    fwd /= np.linalg.norm(fwd)
    eye = mid - fwd * radius * 2.2
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    rel = c - eye
    x, y, z = rel @ right, rel @ down, rel @ fwd
    f = 0.9 * width
    front = z > 1e-3
    u = np.round(f * x[front] / z[front] + width / 2).astype(np.int64)
    v = np.round(f * y[front] / z[front] + height / 2).astype(np.int64)
    zf = z[front]
    size = np.clip(np.ceil(1.2 * f * resolution / zf), 1, 64).astype(np.int64)
    near, far = zf.min(), zf.max()
    shade = 1.0 - 0.45 * (zf - near) / max(far - near, 1e-6)
    shaded = np.clip(col[front] * shade[:, None], 0, 255).astype(np.uint8)
    zbuf = np.full((height, width), np.inf)
    _splat(img, zbuf, u, v, zf, size, shaded)
    return img


def side_by_side(images: list[np.ndarray], titles: list[str], gap: int = 8) -> np.ndarray:
    """Images next to each other on one canvas, each with a title line above it."""
    h = max(im.shape[0] for im in images) + 28
    w = sum(im.shape[1] for im in images) + gap * (len(images) + 1)
    canvas = np.full((h, w, 3), 245, np.uint8)
    x = gap
    for im, title in zip(images, titles, strict=True):
        canvas[28 : 28 + im.shape[0], x : x + im.shape[1]] = im
        cv2.putText(canvas, title, (x, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (20, 20, 20), 1, cv2.LINE_AA)
        x += im.shape[1] + gap
    return canvas


def classes_present(labels: np.ndarray, label_set: LabelSet, *, max_classes: int = LEGEND_MAX_CLASSES,
                    ) -> tuple[list[int], int]:
    """The classes a class-coloured view shows (ids in the label set, unknown 0 aside), most frequent first, at
    most ``max_classes`` of them; and how many more there are."""
    ids = np.asarray(labels).ravel().astype(np.int64)
    ids = ids[(ids > 0) & (ids < len(label_set))]
    counts = np.bincount(ids, minlength=len(label_set))
    order = [int(i) for i in np.argsort(-counts, kind="stable") if counts[i] > 0]
    return order[:max_classes], len(order) - len(order[:max_classes])


def legend_strip(entries: list[tuple[str, np.ndarray]], width: int, *, more: int = 0) -> np.ndarray:
    """A class-colour legend as an RGB image ``width`` wide: a swatch and the name of each entry, in rows, and
    "+N more" when ``more`` classes were left out."""
    font, scale, pad, row_h, swatch = cv2.FONT_HERSHEY_SIMPLEX, 0.45, 8, 22, 14
    items = [(name, tuple(int(c) for c in color)) for name, color in entries]
    if more:
        items.append((f"+{more} more", None))
    placed, x, y = [], pad, 0
    for name, color in items:
        w = (swatch + 5 if color is not None else 0) + cv2.getTextSize(name, font, scale, 1)[0][0] + 3 * pad
        if x + w > width and x > pad:
            x, y = pad, y + row_h
        placed.append((name, color, x, y))
        x += w
    img = np.full((y + row_h + pad, width, 3), 245, np.uint8)
    for name, color, x, y in placed:
        if color is not None:
            cv2.rectangle(img, (x, y + 5), (x + swatch, y + 5 + swatch), color, -1)
            cv2.rectangle(img, (x, y + 5), (x + swatch, y + 5 + swatch), (90, 90, 90), 1)
            x += swatch + 5
        cv2.putText(img, name, (x, y + 17), font, scale, (20, 20, 20), 1, cv2.LINE_AA)
    return img


def with_class_legend(image: np.ndarray, labels: np.ndarray, label_set: LabelSet | None) -> np.ndarray:
    """``image`` with the legend of the classes ``labels`` shows below it (unchanged without a label set or
    classes)."""
    if label_set is None:
        return image
    ids, more = classes_present(labels, label_set)
    if not ids:
        return image
    strip = legend_strip([(label_set.names[i], label_set.colors[i]) for i in ids], image.shape[1], more=more)
    return np.concatenate([image, strip], axis=0)


def write_png(path: str | Path, rgb: np.ndarray) -> int:
    """Write an RGB image as PNG atomically; returns its size in bytes."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise SemmapError(f"{path}: PNG encoding failed")
    write_bytes_atomic(path, buf.tobytes())
    return len(buf)


def render_preview(cloud: MapCloud, label_set: LabelSet | None, poses: list[np.ndarray], *,
                   legend: bool = True) -> np.ndarray:
    """Top-down views of a map's voxels or points: class colours (grey where unclassified) and observed RGB, with
    the legend of the classes shown below (``legend``; :func:`with_class_legend` adds it to a larger picture)."""
    up = up_vector(poses)
    cam_h = max(float(np.asarray(T)[:3, 3] @ up) for T in poses) if poses else None
    cut = None if cam_h is None else cam_h + CEILING_MARGIN
    res = cloud.resolution
    views = [top_down(cloud.centers, cloud.colors, res, up=up, max_height=cut)]
    titles = ["colour (top-down)"]
    if label_set is not None:
        top = cloud.labels
        ok = (top < len(label_set)) & (top != 0)  # no class, or unknown / background: observed grey
        class_colors = muted_grey(cloud.colors)
        class_colors[ok] = label_set.colors[top[ok]]
        views.insert(0, top_down(cloud.centers, class_colors, res, up=up, max_height=cut))
        titles.insert(0, "classes (top-down)")
        views.append(perspective(cloud.centers, class_colors, res, up=up, max_height=cut,
                                 width=views[0].shape[1], height=views[0].shape[0]))
        titles.append("classes (perspective)")
    else:
        views.append(perspective(cloud.centers, cloud.colors, res, up=up, max_height=cut,
                                 width=views[0].shape[1], height=views[0].shape[0]))
        titles.append("colour (perspective)")
    canvas = side_by_side(views, titles)
    return with_class_legend(canvas, cloud.labels, label_set) if legend else canvas
