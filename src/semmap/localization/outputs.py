"""Files of a localization run: ``localization.txt`` (TUM trajectory of the estimates), ``localization.npz``
(covariances, spreads, flags per update), ``report.json`` / ``report.md`` (convergence, errors over time, timings),
``particles.png`` (particles over the map's top-down view at a few moments), ``errors.png`` and, optionally,
``particles.gif``.  Every file is written atomically.
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict
from enum import Enum
from pathlib import Path

import numpy as np

from semmap.files.atomic import write_atomic, write_bytes_atomic, write_text_atomic
from semmap.io.trajectory import write_trajectory
from semmap.localization.prior import PriorMap
from semmap.localization.run import TRUE_CONVERGENCE_DEG, TRUE_CONVERGENCE_M, LocalizationResult
from semmap.viz.preview import classes_present

#: Voxels this far below the ceiling and higher are left out of the top-down view (ceiling, lights).
CEILING_CUT_M = 0.3
#: Panels of particles.png.
PLOT_PANELS = 4


def settings_dict(result: LocalizationResult) -> dict:
    """The filter settings as plain JSON values."""
    def plain(v):
        if isinstance(v, Enum):
            return v.value
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v
    return plain(asdict(result.settings))


def report_dict(result: LocalizationResult, prior: PriorMap, *, sources: dict | None = None) -> dict:
    """report.json: summary, the map's lookup grids, settings and one row per update."""
    rows = []
    for u in result.updates:
        e = u.estimate
        rows.append({"frame": u.index, "t": round(u.timestamp, 6), "converged": e.converged,
                     "spread_m": round(e.spread_m, 4), "spread_deg": round(e.spread_deg, 3),
                     "cluster_mass": round(e.cluster_mass, 4), "fit": round(e.fit, 4), "n_eff": round(e.n_eff, 1),
                     "injected": e.injected, "tempering": round(e.tempering, 4), "sigma_m": round(e.sigma, 4),
                     "pos_err_m": None if u.pos_err_m is None else round(u.pos_err_m, 4),
                     "rot_err_deg": None if u.rot_err_deg is None else round(u.rot_err_deg, 3),
                     "ms": round(e.ms["total"], 2), "scan_points": u.scan_points})
    return {"summary": result.summary(), "map": prior.describe(), "settings": settings_dict(result),
            **({"sources": sources} if sources else {}), "skipped": result.skipped, "updates": rows}


def render_report_md(report: dict, *, title: str = "semmap localize") -> str:
    """report.md: what converged when, errors after convergence, timings, pictures."""
    s = report["summary"]
    lines = [f"# {title}", "", f"Model: **{s['model']}**, {s['particles']} particles, {s['mode']} poses, "
             f"{s['init']} initialisation, motion from {s['motion']}; {s['updates']} updates "
             f"({s['frames_skipped']} frames skipped).", ""]
    lines += _convergence_lines(report)
    if "pos_err_m_after_convergence" in s:
        p, r = s["pos_err_m_after_convergence"], s["rot_err_deg_after_convergence"]
        lines += ["", "| error after the first convergence | median | mean | max |", "|---|---|---|---|",
                  f"| position (cm) | {100 * p['median']:.1f} | {100 * p['mean']:.1f} | {100 * p['max']:.1f} |",
                  f"| rotation (°) | {r['median']:.2f} | {r['mean']:.2f} | {r['max']:.2f} |"]
    if "pos_err_m_final" in s:
        lines += ["", f"Error at the last update: {100 * s['pos_err_m_final']:.1f} cm, {s['rot_err_deg_final']:.2f}°."]
    ms = s["ms_per_update"]
    if ms:
        lines += ["", "| ms per update | mean | median | p95 |", "|---|---|---|---|",
                  f"| filter (motion, weights, resampling, estimate) | {ms['mean']} | {ms['median']} | {ms['p95']} |",
                  f"| scan (back-projection, voxel filter) | {s['ms_per_scan']['mean']} | "
                  f"{s['ms_per_scan']['median']} | {s['ms_per_scan']['p95']} |"]
    with_err = [u for u in report["updates"] if u["pos_err_m"] is not None]
    if with_err:
        lines += ["", "## Error over time", "",
                  "| update | t (s) | filter converged | spread (cm) | error (cm) | error (°) |",
                  "|---|---|---|---|---|---|"]
        picks = sorted(set(np.linspace(0, len(with_err) - 1, min(12, len(with_err))).astype(int).tolist()))
        t0 = report["updates"][0]["t"]
        for i in picks:
            u = with_err[i]
            lines.append(f"| {report['updates'].index(u)} | {u['t'] - t0:.2f} | {u['converged']} | "
                         f"{100 * u['spread_m']:.1f} | {100 * u['pos_err_m']:.1f} | {u['rot_err_deg']:.2f} |")
        lines += ["", "![errors](errors.png)"]
    lines += ["", "![particles](particles.png)", ""]
    return "\n".join(lines)


def _convergence_lines(report: dict) -> list[str]:
    """Two different things, each with its criterion: whether the filter *reports* convergence (its own test on the
    particle cluster, no ground truth), first and at the last update; and whether it converged *on the true pose*
    (its error after that first convergence, against ground truth)."""
    s, c, last = report["summary"], report["settings"], report["updates"][-1] if report["updates"] else None
    rule = (f"the filter's own test, without ground truth: its strongest particle cluster holds at least "
            f"{100 * c['converged_mass']:.0f} % of the weight within {100 * c['converged_m']:.0f} cm and "
            f"{c['converged_deg']:g}° (spread) and {100 * c['converged_fit']:.0f} % of the scan lies on the map at "
            f"its pose.")
    if s["frames_to_converge"] is None:
        lines = [f"The filter did **not** converge by {rule}"]
    else:
        lines = [f"Converged after **{s['frames_to_converge']} updates** ({s['seconds_to_converge']} s of the "
                 f"sequence) by {rule}"]
    if last is not None:
        lines[0] += (" At the last update it still did." if last["converged"] else
                     f" At the last update it did not (cluster of {100 * last['cluster_mass']:.0f} % of the weight, "
                     f"spread {100 * last['spread_m']:.1f} cm and {last['spread_deg']:.1f}°, "
                     f"{100 * last['fit']:.0f} % of the scan on the map).")
    if "converged_to_truth" in s:
        if "pos_err_m_after_convergence" in s:
            p, r = s["pos_err_m_after_convergence"], s["rot_err_deg_after_convergence"]
            err = f"the median error after the first convergence is {100 * p['median']:.1f} cm and {r['median']:.2f}°"
        else:
            err = "it never reported convergence"
        lines += ["", f"On the true pose (against ground truth: the median error after the first convergence within "
                      f"{100 * TRUE_CONVERGENCE_M:.0f} cm and {TRUE_CONVERGENCE_DEG:g}°): "
                      f"**{'yes' if s['converged_to_truth'] else 'no'}**; {err}."]
    return lines


def write_outputs(out_dir: str | Path, result: LocalizationResult, prior: PriorMap, *, gif: bool = False,
                  sources: dict | None = None, title: str = "semmap localize") -> dict[str, Path]:
    """Write every output of a run into ``out_dir``; returns ``{file name: path}``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"localization.txt": write_trajectory(out / "localization.txt", result.trajectory())}
    ups = result.updates
    arrays = {"timestamps": np.array([u.timestamp for u in ups]),
              "poses": np.array([u.estimate.T_world_cam for u in ups]).reshape(-1, 4, 4),
              "covariances": np.array([u.estimate.covariance for u in ups]).reshape(-1, 6, 6),
              "converged": np.array([u.estimate.converged for u in ups]),
              "spread_m": np.array([u.estimate.spread_m for u in ups]),
              "spread_deg": np.array([u.estimate.spread_deg for u in ups]),
              "pos_err_m": np.array([np.nan if u.pos_err_m is None else u.pos_err_m for u in ups]),
              "rot_err_deg": np.array([np.nan if u.rot_err_deg is None else u.rot_err_deg for u in ups])}
    files["localization.npz"] = write_atomic(out / "localization.npz", lambda f: np.savez_compressed(f, **arrays))
    report = report_dict(result, prior, sources=sources)
    files["report.json"] = write_text_atomic(out / "report.json", json.dumps(report, indent=1) + "\n")
    files["report.md"] = write_text_atomic(out / "report.md", render_report_md(report, title=title))
    files["particles.png"] = write_bytes_atomic(out / "particles.png", particles_png(result, prior))
    if any(u.pos_err_m is not None for u in ups):
        files["errors.png"] = write_bytes_atomic(out / "errors.png", errors_png(result))
    if gif:
        files["particles.gif"] = write_bytes_atomic(out / "particles.gif", particles_gif(result, prior))
    return files


# ---------------------------------------------------------------------------------------------- pictures
def _map_below_ceiling(prior: PriorMap) -> tuple[np.ndarray, np.ndarray | None]:
    """The occupied voxel centres a top-down view shows (those below the ceiling cut) and their most probable
    class (None for a map without classes)."""
    c = prior.centers.astype(np.float64)
    keep = c[:, 2] < prior.ceiling_z - CEILING_CUT_M
    if not keep.any():
        keep[:] = True
    if prior.class_probs is None or prior.label_set is None:
        return c[keep], None
    return c[keep], prior.class_probs[keep].argmax(axis=1)


def map_image(prior: PriorMap) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """Top-down RGB image of the map's occupied voxels below the ceiling (class colours where the map has classes,
    grey by height otherwise) and its extent (x0, x1, y0, y1) in metres."""
    c, cls = _map_below_ceiling(prior)
    res = prior.resolution
    lo = c[:, :2].min(axis=0) - res
    ij = np.round((c[:, :2] - lo) / res).astype(np.int64)  # centres lie on the lattice: round, not floor
    w, h = ij.max(axis=0) + 2
    img = np.full((h, w, 3), 245, np.uint8)
    order = np.argsort(c[:, 2], kind="stable")  # higher voxels drawn last
    if cls is not None:
        colors = prior.label_set.colors[cls]
    else:
        z = (c[:, 2] - c[:, 2].min()) / max(np.ptp(c[:, 2]), 1e-6)
        colors = np.repeat((90 + 120 * z)[:, None], 3, axis=1).astype(np.uint8)
    img[ij[order, 1], ij[order, 0]] = colors[order]
    return img[::-1], (float(lo[0]), float(lo[0] + w * res), float(lo[1]), float(lo[1] + h * res))


def add_class_legend(fig, prior: PriorMap) -> None:
    """Below the panels, the colour of every class the map image shows (most voxels first; none for a map
    without classes), so that the particles can be read against the furniture."""
    from matplotlib.patches import Patch

    _, cls = _map_below_ceiling(prior)
    if cls is None:
        return
    ids, more = classes_present(cls, prior.label_set)
    handles = [Patch(facecolor=prior.label_set.colors[i] / 255.0, edgecolor="0.4", label=prior.label_set.names[i])
               for i in ids]
    if more:
        handles.append(Patch(facecolor="none", edgecolor="none", label=f"+{more} more"))
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 8), fontsize=8,
                   frameon=False, title="map classes", title_fontsize=8)


def _moments(result: LocalizationResult, panels: int = PLOT_PANELS) -> list[int]:
    """Update indices to show: the first, the moment of convergence (or the middle), one between, the last."""
    keys = sorted(result.snapshots)
    first_conv = result.first_converged()
    wanted = [keys[0], keys[len(keys) // 4], first_conv if first_conv is not None else keys[len(keys) // 2], keys[-1]]
    return sorted({min(keys, key=lambda s, k=k: abs(s - k)) for k in wanted[:panels]})


def _draw(ax, result: LocalizationResult, k: int, img: np.ndarray, extent) -> None:
    ax.imshow(img, extent=extent, interpolation="nearest")
    p = result.snapshots[k]
    ax.scatter(p[:, 0], p[:, 1], s=2, c="tab:blue", alpha=0.35, linewidths=0, label="particles")
    gt = np.array([result.ground_truth[i][:3, 3] for i in sorted(result.ground_truth) if i <= k]).reshape(-1, 3)
    est = np.array([u.estimate.T_world_cam[:3, 3] for u in result.updates[: k + 1]])
    if len(gt):
        ax.plot(gt[:, 0], gt[:, 1], color="black", lw=1.2, label="ground truth")
    ax.plot(est[:, 0], est[:, 1], color="tab:red", lw=1.0, label="estimate")
    e = result.updates[k].estimate
    ax.plot(*est[-1, :2], marker="o", color="tab:red", ms=5)
    state = "converged" if e.converged else f"cluster of {e.cluster_mass:.0%}, spread {100 * e.spread_m:.0f} cm"
    ax.set_title(f"update {k}: {state}", fontsize=9)
    # the map's extent, widened to the camera's path where it leaves the mapped part (a map of another walk)
    seen = np.concatenate([est[:, :2], gt[:, :2]]) if len(gt) else est[:, :2]
    ax.set_xlim(min(extent[0], seen[:, 0].min() - 0.2), max(extent[1], seen[:, 0].max() + 0.2))
    ax.set_ylim(min(extent[2], seen[:, 1].min() - 0.2), max(extent[3], seen[:, 1].max() + 0.2))
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)


def particles_png(result: LocalizationResult, prior: PriorMap) -> bytes:
    """PNG of :func:`particles_figure`."""
    buf = io.BytesIO()
    particles_figure(result, prior).savefig(buf, format="png")
    return buf.getvalue()


def particles_figure(result: LocalizationResult, prior: PriorMap):
    """Particles, ground truth and estimate over the map's top-down view at a few moments, the map's classes in a
    legend below (a matplotlib Figure)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    img, extent = map_image(prior)
    moments = _moments(result)
    fig = Figure(figsize=(4.2 * len(moments), 4.4 + (0.5 if prior.class_probs is not None else 0.0)), dpi=100,
                 layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(moments), squeeze=False)[0]
    for ax, k in zip(axes, moments, strict=True):
        _draw(ax, result, k, img, extent)
    axes[0].legend(fontsize=7, loc="upper right")
    s = result.settings
    fig.suptitle(f"{s.model.value} model, {s.particles} particles, {result.init.value} initialisation", fontsize=10)
    add_class_legend(fig, prior)
    return fig


def errors_png(result: LocalizationResult) -> bytes:
    """PNG: position and rotation error, and the particle spread, over the updates."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ups = result.updates
    idx = np.arange(len(ups))
    pos = np.array([np.nan if u.pos_err_m is None else 100 * u.pos_err_m for u in ups])
    rot = np.array([np.nan if u.rot_err_deg is None else u.rot_err_deg for u in ups])
    spread = np.array([100 * u.estimate.spread_m for u in ups])
    fig = Figure(figsize=(9, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    a, b = fig.subplots(2, 1, sharex=True)
    a.semilogy(idx, np.maximum(pos, 0.05), label="position error (cm)")
    a.semilogy(idx, np.maximum(spread, 0.05), ls="--", label="cluster spread (cm)")
    b.semilogy(idx, np.maximum(rot, 1e-3), color="tab:green", label="rotation error (°)")
    first = result.first_converged()
    for ax in (a, b):
        if first is not None:
            ax.axvline(first, color="black", lw=0.8, ls=":", label="converged")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    b.set_xlabel("update")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def particles_gif(result: LocalizationResult, prior: PriorMap, *, max_frames: int = 60) -> bytes:
    """Animated GIF of the particles over the map, one frame per snapshot (at most ``max_frames``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from PIL import Image

    img, extent = map_image(prior)
    keys = sorted(result.snapshots)
    keys = [keys[i] for i in sorted(set(np.linspace(0, len(keys) - 1, min(max_frames, len(keys))).astype(int)))]
    frames = []
    for k in keys:
        fig = Figure(figsize=(5, 5), dpi=80)
        canvas = FigureCanvasAgg(fig)
        _draw(fig.subplots(), result, k, img, extent)
        fig.tight_layout()
        canvas.draw()
        rgb = np.asarray(canvas.buffer_rgba())[..., :3]
        frames.append(Image.fromarray(rgb).convert("P", palette=Image.Palette.ADAPTIVE))
    buf = io.BytesIO()
    frames[0].save(buf, format="GIF", save_all=True, append_images=frames[1:], duration=150, loop=0)
    return buf.getvalue()
