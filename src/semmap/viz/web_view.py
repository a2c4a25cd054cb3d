"""The map in a web browser: one self-contained HTML view of a map in 3D, to turn, zoom and hide classes in.

Each class is one plotly trace of square markers at the voxel (or point) centres, in the class colour, so the
legend hides and shows a class with a click (a double click shows it alone); a button switches every voxel to its
observed colour and back. Object boxes (upright, with ``id class`` above each) and the camera path are traces of
their own. plotly's JavaScript is written into the page, so it opens offline and needs nothing else. Past
:data:`VOXEL_BUDGET` voxels a seeded sample of them is drawn, and the page says how many were left out.
"""

from __future__ import annotations

import base64
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.files.atomic import write_text_atomic
from semmap.types import LabelSet, MapCloud

log = logging.getLogger("semmap")
#: Most voxels one view draws: about 26 bytes each in the page (position and observed colour), so with plotly's
#: own 4.7 MB the demo's view stays well under 15 MB.
VOXEL_BUDGET = 200_000
#: Colour of voxels without a class (or of every voxel of a map without classes).
NO_CLASS_RGB = (150, 150, 150)
#: Seed of the sample drawn past the budget (the same map gives the same page).
SAMPLE_SEED = 0
CAMERA_PATH_RGB = "rgb(255, 120, 0)"
BOX_RGB = "rgb(20, 20, 20)"
#: The plotly config of every view: no logo, a PNG of the current view from the toolbar.
PLOTLY_CONFIG = {"displaylogo": False, "responsive": True,
                 "toImageButtonOptions": {"format": "png", "filename": "semmap-map"}}
#: The 12 edges of a box, as pairs of its corners numbered by the signs of (x, y, z): bit 0 x, bit 1 y, bit 2 z.
_BOX_EDGES = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7))


@dataclass(frozen=True)
class ViewContent:
    """What a view drew: voxels in the map, voxels drawn, classes, objects and camera poses, and the line saying
    what was left out (empty when nothing was)."""

    voxels: int
    drawn: int
    classes: tuple[str, ...]
    objects: int
    poses: int
    note: str


def _hex(rgb: np.ndarray) -> list[str]:
    """``#rrggbb`` strings of (N, 3) uint8 colours."""
    rgb = np.asarray(rgb, np.uint32).reshape(-1, 3)
    packed = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    return [f"#{v:06x}" for v in packed.tolist()]


def _css(rgb: Sequence[int]) -> str:
    return f"rgb({int(rgb[0])}, {int(rgb[1])}, {int(rgb[2])})"


def sample(n: int, budget: int) -> np.ndarray:
    """Indices of the voxels drawn: all of them up to ``budget``, else a seeded sample of ``budget``, in order."""
    if n <= budget:
        return np.arange(n)
    return np.sort(np.random.default_rng(SAMPLE_SEED).choice(n, budget, replace=False))


def box_edges(center: Sequence[float], rotation: Sequence[Sequence[float]], extent: Sequence[float]) -> np.ndarray:
    """(36, 3) points: the 12 edges of an oriented box (``rotation``'s columns its axes), each as two corners and a
    NaN gap, as a plotly line trace draws them."""
    c, R, half = np.asarray(center, float), np.asarray(rotation, float), np.asarray(extent, float) / 2
    signs = np.array([[1 if i & 1 else -1, 1 if i & 2 else -1, 1 if i & 4 else -1] for i in range(8)], float)
    corners = c + (signs * half) @ R.T
    out = np.full((len(_BOX_EDGES) * 3, 3), np.nan)
    for j, (a, b) in enumerate(_BOX_EDGES):
        out[3 * j], out[3 * j + 1] = corners[a], corners[b]
    return out


def _above(box: dict, up: Sequence[float]) -> np.ndarray:
    """A point 5 cm above a box's top face (along ``up``), where its label goes."""
    up = np.asarray(up, float)
    axes_up = np.asarray(box["rotation"], float).T @ up  # each box axis along up
    half_height = 0.5 * float(np.abs(np.asarray(box["extent"], float)) @ np.abs(axes_up))
    return np.asarray(box["center"], float) + up * (half_height + 0.05)


def _class_groups(labels: np.ndarray, label_set: LabelSet | None
                  ) -> list[tuple[str, tuple[int, int, int] | None, np.ndarray]]:
    """(name, colour, indices) per class present, the most frequent first, voxels without a class last; without a
    label set one group in the file's own colours (colour None)."""
    if label_set is None:
        return [("voxels", None, np.arange(len(labels)))]
    labels = np.asarray(labels).astype(np.int64)
    known = (labels > 0) & (labels < len(label_set))
    counts = np.bincount(labels[known], minlength=len(label_set))
    groups = [(label_set.names[c], tuple(int(v) for v in label_set.colors[c]), np.flatnonzero(labels == c))
              for c in np.argsort(-counts, kind="stable") if counts[c] > 0]
    rest = np.flatnonzero(~known)
    if len(rest):
        groups.append(("no class", NO_CLASS_RGB, rest))
    return groups


def typed_array(values: np.ndarray) -> dict:
    """plotly.js's typed-array form of a float32 array (dtype and base64 bytes): 16 bytes a point in the page
    where decimal text takes about 30."""
    return {"dtype": "f4", "bdata": base64.b64encode(np.ascontiguousarray(values, "<f4").tobytes()).decode("ascii")}


def _scatter(points: np.ndarray, **props) -> dict:
    """A ``scatter3d`` trace through (N, 3) points (NaN: a gap in a line)."""
    p = np.asarray(points, np.float32).reshape(-1, 3)
    return {"type": "scatter3d", **{axis: typed_array(p[:, i]) for i, axis in enumerate("xyz")}, **props}


def map_figure(cloud: MapCloud, label_set: LabelSet | None, *, objects: Sequence[dict] = (),
               camera_positions: np.ndarray | None = None, up: Sequence[float] = (0.0, 0.0, 1.0),
               budget: int = VOXEL_BUDGET, title: str = "the map in 3D") -> tuple[dict, ViewContent]:
    """A plotly figure (as a dict: plotly.js's own schema, checked by the browser tests rather than plotly.py's
    slower validators) of the map (``cloud``'s voxels or points by class), its objects' boxes (records as in
    ``objects.json``) and the camera path (``camera_positions`` (N, 3)); returns it and what it holds."""
    n = len(cloud)
    keep = sample(n, budget)
    centers = np.asarray(cloud.centers, np.float32)[keep]
    labels = np.asarray(cloud.labels)[keep] if label_set is not None else np.zeros(len(keep), np.uint16)
    observed = np.asarray(cloud.colors, np.uint8)[keep]
    marker_px = 3 if len(keep) < 60_000 else 2
    traces: list[dict] = []
    groups = _class_groups(labels, label_set)
    class_colours, rgb_colours = [], []
    for name, rgb, idx in groups:
        colour = _hex(observed[idx]) if rgb is None else _css(rgb)
        traces.append(_scatter(centers[idx], mode="markers", name=f"{name} ({len(idx):,})", legendgroup=name,
                               marker={"size": marker_px, "symbol": "square", "color": colour, "line": {"width": 0}},
                               hovertemplate=f"{name}<br>%{{x:.2f}}, %{{y:.2f}}, %{{z:.2f}} m<extra></extra>"))
        class_colours.append(colour)
        rgb_colours.append(_hex(observed[idx]))
    buttons = [] if label_set is None else [  # a map without classes is drawn in its own colours, nothing to toggle
        {"type": "buttons", "direction": "right", "x": 0.01, "y": 0.0, "xanchor": "left", "yanchor": "bottom",
         "showactive": True, "buttons": [
             {"label": "class colours", "method": "restyle",
              "args": [{"marker.color": class_colours}, list(range(len(groups)))]},
             {"label": "RGB", "method": "restyle", "args": [{"marker.color": rgb_colours}, list(range(len(groups)))]}]}]
    if objects:
        edges = np.concatenate([box_edges(o["box"]["center"], o["box"]["rotation"], o["box"]["extent"])
                                for o in objects])
        traces.append(_scatter(edges, mode="lines", name=f"objects ({len(objects)})", legendgroup="objects",
                               line={"color": BOX_RGB, "width": 3}, hoverinfo="skip"))
        tops = np.array([_above(o["box"], up) for o in objects])
        traces.append(_scatter(tops, mode="text", legendgroup="objects", showlegend=False, hoverinfo="text",
                               text=[f"{o['id']} {o['class']}" for o in objects],
                               textfont={"size": 11, "color": BOX_RGB}))
    poses = 0 if camera_positions is None else len(camera_positions)
    if poses:
        c = np.asarray(camera_positions, np.float32).reshape(-1, 3)
        traces.append(_scatter(c, mode="lines", name=f"camera path ({poses} poses)", hoverinfo="skip",
                               line={"color": CAMERA_PATH_RGB, "width": 4}))
    note = "" if len(keep) == n else (f"{len(keep):,} of the map's {n:,} voxels drawn (a seeded sample); "
                                      f"{n - len(keep):,} left out to keep the page small")
    layout = dict(
        title={"text": title + (f"<br><sup>{note}</sup>" if note else ""), "x": 0.01},
        scene={"aspectmode": "data", **{f"{a}axis": {"title": {"text": f"{a} (m)"}} for a in "xyz"},
               "camera": {"up": dict(zip("xyz", (float(v) for v in up), strict=True))}},
        legend={"title": {"text": "click: hide / show; double-click: only this"}, "itemsizing": "constant"},
        margin={"l": 0, "r": 0, "t": 60, "b": 0}, height=720, paper_bgcolor="white", updatemenus=buttons)
    fig = {"data": traces, "layout": layout}
    content = ViewContent(voxels=n, drawn=len(keep), classes=tuple(name for name, _, _ in groups),
                          objects=len(objects), poses=poses, note=note)
    return fig, content


def view_html(fig: dict, *, full_html: bool = True, div_id: str = "semmap-map-view") -> str:
    """The figure as HTML with plotly's JavaScript inlined (no network): a whole page, or a ``<div>`` to embed."""
    import plotly.io

    return plotly.io.to_html(fig, include_plotlyjs=True, full_html=full_html, config=PLOTLY_CONFIG, div_id=div_id,
                             default_width="100%", default_height="720px", validate=False)


def write_view_html(path: str | Path, fig: dict) -> Path:
    """Write the figure as one self-contained HTML page (atomically)."""
    return write_text_atomic(path, view_html(fig))


def run_extras(folder: Path) -> tuple[list[dict], np.ndarray | None]:
    """The object records (``objects.json``) and camera poses (``trajectory.txt``, (N, 4, 4)) of the run folder a
    map lies in, where they are; a file that cannot be read is left out with a warning (the map is still shown)."""
    from semmap.errors import SemmapError
    from semmap.io.objects import read_objects_json
    from semmap.io.trajectory import read_trajectory

    objects: list[dict] = []
    poses = None
    try:
        if (folder / "objects.json").is_file():
            objects = read_objects_json(folder / "objects.json")
        if (folder / "trajectory.txt").is_file():
            poses = read_trajectory(folder / "trajectory.txt").poses
    except SemmapError as exc:
        log.warning("the 3D view leaves it out: %s", exc)
    return objects, poses


def figure_of(cloud: MapCloud, label_set: LabelSet | None, *, objects: Sequence[dict] = (),
              poses: np.ndarray | None = None, budget: int = VOXEL_BUDGET,
              title: str = "the map in 3D") -> tuple[dict, ViewContent]:
    """:func:`map_figure` with the camera path and the world's up direction taken from camera ``poses``."""
    from semmap.viz.preview import up_vector

    poses = None if poses is None or len(poses) == 0 else np.asarray(poses, float).reshape(-1, 4, 4)
    return map_figure(cloud, label_set, objects=objects, budget=budget, title=title,
                      camera_positions=None if poses is None else poses[:, :3, 3],
                      up=(0.0, 0.0, 1.0) if poses is None else up_vector(poses))


def write_map_view(map_path: str | Path, out: str | Path, *, budget: int = VOXEL_BUDGET) -> ViewContent:
    """``semmap view MAP --html OUT``: any map file ``semmap view`` opens, in 3D as one offline page, with the
    objects and camera path of the run folder it lies in (``out`` checked against the map first); returns what the
    page shows."""
    from semmap.errors import FormatError
    from semmap.files.outputs import OutputKind, check_outputs
    from semmap.viz.rerun_log import map_file_cloud
    from semmap.viz.rerun_products import is_product_file

    map_path = Path(map_path)
    check_outputs([("--html", out, OutputKind.FILE)], [("MAP", map_path)])
    if is_product_file(map_path):
        raise FormatError(f"{map_path}: --html draws map files (.semmap, .ply, .ot, .bt), not the products beside "
                          "them; open this one without --html")
    cloud, label_set = map_file_cloud(map_path)
    objects, poses = run_extras(map_path.parent)
    fig, content = figure_of(cloud, label_set, objects=objects, poses=poses, budget=budget,
                             title=f"{map_path.name}: {len(cloud):,} voxels at {cloud.resolution:g} m")
    write_view_html(out, fig)
    return content
