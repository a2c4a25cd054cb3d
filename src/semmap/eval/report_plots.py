"""Pictures for ``report.md`` / ``report.html`` (matplotlib, written atomically as PNG): the trajectory from above
against ground truth and over the map, per-class IoU, storage per representation and time per stage.

Each plot is drawn only when the report has its data; :func:`write_report_plots` returns ``{name: file name}``.
"""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np

from semmap.files.atomic import write_bytes_atomic
from semmap.poses.track import GROUND_TRUTH
from semmap.types import MapCloud, Trajectory, transform_points

#: File names of the plots, by the report section they belong to.
PLOT_FILES = {"trajectory": "report_trajectory.png", "iou": "report_iou.png", "storage": "report_storage.png",
              "timings": "report_timings.png"}
#: The map is drawn under the trajectory only when its footprint has at most this many cells.
MAX_BACKGROUND_CELLS = 16_000_000
#: Report keys that are totals or bookkeeping, not stages, in ``ms_per_frame``.
NOT_STAGES = ("total",)


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> Path:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return write_bytes_atomic(path, buffer.getvalue())


def axis_label(direction: np.ndarray) -> str:
    """An axis of a plot from above named by the world axis it runs along (``x (m)``, ``−z (m)``), or by its
    direction when it runs along none."""
    d = np.asarray(direction, float)
    i = int(np.argmax(np.abs(d)))
    if abs(d[i]) > 0.999:
        return f"{'−' if d[i] < 0 else ''}{'xyz'[i]} (m)"
    return f"m along ({d[0]:.2f}, {d[1]:.2f}, {d[2]:.2f})"


def plot_trajectory(path: Path, used: Trajectory, ground_truth: Trajectory | None, *, cloud: MapCloud | None = None,
                    up: np.ndarray | None = None, label: str = "poses used", ate_m: float | None = None) -> Path:
    """The camera path from above over the map (occupied voxels counted per column, grey), and the ground truth when
    it differs from the poses used (all in one frame: the caller moves estimated poses and their map onto it); the
    axes are preview.png's and named by the world axes they run along."""
    from semmap.viz.preview import _horizontal_axes, up_vector

    up = up_vector(used.poses) if up is None else np.asarray(up, float)
    a, b = _horizontal_axes(up)  # the axes of preview.png's top-down views: the two pictures show the same view
    fig = _figure(7.5, 6.5)
    ax = fig.add_subplot(1, 1, 1)
    if cloud is not None and len(cloud):
        # the map from above: occupied voxels per column, so walls (tall stacks) are dark and floors light
        u, v = cloud.centers @ a, cloud.centers @ b
        res = cloud.resolution
        bins = [np.arange(u.min(), u.max() + 2 * res, res), np.arange(v.min(), v.max() + 2 * res, res)]
        if len(bins[0]) * len(bins[1]) <= MAX_BACKGROUND_CELLS:
            counts, ue, ve = np.histogram2d(u, v, bins=bins)
            shade = np.ma.masked_equal(np.log1p(counts.T), 0)
            ax.imshow(shade, origin="lower", extent=(ue[0], ue[-1], ve[0], ve[-1]), cmap="Greys", vmin=0,
                      vmax=max(float(shade.max()) * 1.3, 1e-9), interpolation="nearest", aspect="equal")
            ax.plot([], [], "s", color="0.55", label="map (occupied voxels per column)")
    if ground_truth is not None and len(ground_truth):
        g = ground_truth.positions
        ax.plot(g @ a, g @ b, color="black", lw=2.2, label="ground truth")
    p = used.positions
    name = label if ate_m is None else f"{label} (ATE {100 * ate_m:.2f} cm)"
    ax.plot(p @ a, p @ b, color="tab:orange", lw=1.3, label=name)
    ax.plot(p[:1] @ a, p[:1] @ b, "o", color="tab:green", ms=6, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(axis_label(a))
    ax.set_ylabel(axis_label(b))
    ax.set_title("camera trajectory, seen from above (as in preview.png)")
    ax.grid(alpha=0.3)
    fig.legend(fontsize=8, loc="outside lower center", ncol=2)
    return _save(fig, path)


def plot_iou(path: Path, series: dict[str, dict[str, float]], *, title: str) -> Path:
    """Horizontal bars of IoU per class, one bar per series (e.g. the map and its network at the same pixels)."""
    first = next(iter(series.values()), {})
    names = sorted(set().union(*series.values()), key=lambda n: (first.get(n, -1.0), n))
    y = np.arange(len(names))
    fig = _figure(7.5, 1.2 + 0.28 * max(len(names), 1))
    ax = fig.add_subplot(1, 1, 1)
    h = 0.8 / max(len(series), 1)
    for i, ((label, per_class), colour) in enumerate(zip(series.items(), ("tab:blue", "tab:gray"), strict=False)):
        ax.barh(y + (len(series) - 1) * h / 2 - i * h, [per_class.get(n, 0.0) for n in names], h, color=colour,
                label=label)
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xlim(0, 1)
    ax.set_xlabel("IoU")
    ax.set_title(title)
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    return _save(fig, path)


def iou_at_pixels(report: dict) -> bool:
    """Whether the IoU plot compares the map with a segmenter at the same pixels (label images as semantics are no
    network to compare with)."""
    return bool(report.get("segmenter") and report.get("pixel_per_class_iou_map")
                and report.get("pixel_per_class_iou_network"))


def iou_series(report: dict) -> tuple[dict[str, dict[str, float]], str] | None:
    """What the IoU plot shows: the map against its network at the same pixels where the run has it, else the 3D
    map against the ground-truth voxels alone (never a voxel IoU beside a pixel IoU); None without either."""
    if iou_at_pixels(report):
        return ({"map": report["pixel_per_class_iou_map"], report["segmenter"]: report["pixel_per_class_iou_network"]},
                "IoU per class, map vs network at the same pixels")
    if report.get("per_class_iou_3d"):
        return {"3D map": report["per_class_iou_3d"]}, "IoU per class, 3D map vs ground-truth voxels"
    return None


def _human_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:,.0f} {unit}" if unit == "B" else f"{n:,.1f} {unit}"
        n /= 1024
    return f"{n:,.1f} GiB"


def plot_storage(path: Path, sizes: dict[str, int]) -> Path:
    """Horizontal bars of bytes per representation on a log scale, each labelled with its size."""
    names = list(sizes)
    values = np.array([max(sizes[n], 1) for n in names], float)
    fig = _figure(7.5, 1.3 + 0.45 * len(names))
    ax = fig.add_subplot(1, 1, 1)
    y = np.arange(len(names))[::-1]
    ax.barh(y, values, color=["tab:red" if "dense" in n else "tab:blue" for n in names])
    for yi, v in zip(y, values, strict=True):
        ax.text(v * 1.15, yi, _human_bytes(v), va="center", fontsize=8)
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xscale("log")
    ax.set_xlim(values.min() / 3, values.max() * 20)
    ax.set_xlabel("bytes (log scale)")
    ax.set_title("storage of the same scene")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, path)


def plot_timings(path: Path, ms_per_frame: dict[str, float]) -> Path:
    """Horizontal bars of milliseconds per frame per stage, with the total in the title."""
    stages = {k: v for k, v in ms_per_frame.items() if k not in NOT_STAGES}
    names = list(stages)
    values = np.array([stages[n] for n in names], float)
    total = ms_per_frame.get("total", float(values.sum()))
    fig = _figure(7.5, 1.3 + 0.32 * max(len(names), 1))
    ax = fig.add_subplot(1, 1, 1)
    y = np.arange(len(names))[::-1]
    ax.barh(y, values, color="tab:purple")
    for yi, v in zip(y, values, strict=True):
        ax.text(v + 0.01 * max(values.max(), 1e-9), yi, f"{v:.1f}", va="center", fontsize=8)
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xlim(0, max(values.max(), 1e-9) * 1.15)
    ax.set_xlabel("ms per frame")
    ax.set_title(f"time per stage ({total:.1f} ms per frame in all)")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, path)


def storage_sizes(report: dict) -> dict[str, int]:
    """Bytes per representation from a report: the dense cloud, each map file, the map in memory."""
    sizes: dict[str, int] = {}
    if "dense_point_cloud_bytes" in report:
        sizes["dense point cloud (PLY)"] = int(report["dense_point_cloud_bytes"])
    for name, n in report.get("bytes_on_disk", {}).items():
        if not name.endswith(".png") and name != "cloud.ply":  # (the dense cloud above)
            sizes[name] = int(n)
    if "bytes_in_memory" in report:
        sizes["in memory"] = int(report["bytes_in_memory"])
    return sizes


def _trajectory_in_one_frame(report: dict, used: Trajectory, ground_truth: Trajectory | None,
                             cloud: MapCloud | None) -> dict:
    """:func:`plot_trajectory`'s arguments with everything in the ground truth's frame: estimated poses and the map
    built from them moved by the report's ``map_alignment`` (the ATE's SE(3) fit); without one, the ground truth is
    left out rather than drawn in another frame."""
    source = report.get("poses", "?")
    if ground_truth is not None and source == GROUND_TRUTH:
        return {"used": used, "ground_truth": None, "cloud": cloud, "label": "ground-truth poses"}
    ate = report.get("trajectory_vs_ground_truth", {}).get("ate_rmse_m")
    T = report.get("map_alignment", {}).get("T_gt_map")
    if T is None:
        return {"used": used, "ground_truth": None, "cloud": cloud, "label": f"poses used ({source})", "ate_m": ate}
    T = np.asarray(T, np.float64)
    moved = Trajectory(used.timestamps, T @ used.poses, used.names)
    if cloud is not None:
        cloud = dataclasses.replace(cloud, centers=transform_points(T, cloud.centers))
    return {"used": moved, "ground_truth": ground_truth, "cloud": cloud, "ate_m": ate,
            "label": f"poses used ({source}), aligned to the ground truth"}


def write_report_plots(out_dir: str | Path, report: dict, *, used: Trajectory | None = None,
                       ground_truth: Trajectory | None = None, cloud: MapCloud | None = None) -> dict[str, str]:
    """Every plot the report has data for, into ``out_dir``; returns ``{section: file name}``."""
    out_dir = Path(out_dir)
    plots: dict[str, str] = {}
    if used is not None and len(used) >= 2:
        plot_trajectory(out_dir / PLOT_FILES["trajectory"], **_trajectory_in_one_frame(report, used, ground_truth,
                                                                                         cloud))
        plots["trajectory"] = PLOT_FILES["trajectory"]
    iou = iou_series(report)
    if iou is not None:
        plot_iou(out_dir / PLOT_FILES["iou"], iou[0], title=iou[1])
        plots["iou"] = PLOT_FILES["iou"]
    sizes = storage_sizes(report)
    if sizes:
        plot_storage(out_dir / PLOT_FILES["storage"], sizes)
        plots["storage"] = PLOT_FILES["storage"]
    if report.get("ms_per_frame"):
        plot_timings(out_dir / PLOT_FILES["timings"], report["ms_per_frame"])
        plots["timings"] = PLOT_FILES["timings"]
    return plots
