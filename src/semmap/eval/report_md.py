"""``report.md``: a human-readable summary of a run's report (accuracy, storage, timings)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.eval.headline import SAME_PIXELS, VOXELS_3D, segmenter_of
from semmap.eval.report_plots import iou_at_pixels
from semmap.files.atomic import write_text_atomic
from semmap.viz.web_view import ViewContent

#: Where report.html puts the map's 3D view (an HTML comment: invisible in report.md itself).
MAP_VIEW_MARKER = "<!-- semmap: the map in 3D -->"


def _continued_lines(c: dict | None) -> list[str]:
    """``--continue``: the prior this run went on from and how the recording was aligned to it."""
    if not c:
        return []
    icp = c.get("icp", {})
    fit = (f"ICP against the prior's {c['icp_surface']} moved it by {100 * c['icp_correction_m']:.2f} cm / "
           f"{c['icp_correction_deg']:.2f}° ({icp.get('iterations')} iterations, RMS point-to-plane residual "
           f"{100 * icp.get('rms_residual_m', 0.0):.2f} cm, {100 * icp.get('inlier_fraction', 0.0):.0f}% of the "
           "points matched)" if icp.get("used") else f"ICP not applied ({icp.get('why', 'off')})")
    t = c["translation_m"]
    return ["## Continued from a prior map", "",
            f"Prior: `{c['prior']}` ({', '.join(c['maps'])}). The recording's first frames were localized in it by "
            f"Monte-Carlo localization: converged after {c['converged_after_frames']} frames (estimate taken after "
            f"{c['frames_localized']}), particle spread {100 * c['particle_spread_m']:.1f} cm / "
            f"{c['particle_spread_deg']:.2f}°, {100 * c['scan_fit']:.0f}% of the scan on the map; {fit}.", "",
            f"Recording -> prior transform: translation ({t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}) m, rotation "
            f"{c['rotation_deg']:.2f}° (yaw {c['yaw_deg']:.2f}°); `continued.T_prior_seq` in report.json. Every pose "
            "was carried into the prior's frame and the prior's evidence kept accumulating.", ""]


def _kb(n: float) -> str:
    return f"{n / 1024:,.1f} KiB" if n < 1024**2 else f"{n / 1024**2:,.2f} MiB"


def _plot(plots: dict[str, str] | None, section: str, caption: str) -> list[str]:
    """The Markdown image line of a report plot (``eval.report_plots``), when it was drawn."""
    return [f"![{caption}]({plots[section]})", ""] if plots and section in plots else []


def render_report_md(report: dict, *, title: str = "semmap run", plots: dict[str, str] | None = None,
                     map_view: ViewContent | None = None) -> str:
    """Markdown for a report dict as written by the pipeline; ``plots`` names the pictures of
    :func:`semmap.eval.report_plots.write_report_plots` by section, ``map_view`` what report.html's 3D view of the
    map shows (its place marked for :mod:`semmap.eval.report_html`)."""
    lines = [f"# {title}", "", f"Dataset: `{report.get('dataset', '?')}`  ", *_realism_line(report),
             f"Resolution: {report['resolution']} m  ",
             *([f"Semantics: {report['semantics']}  "] if "semantics" in report else []),
             f"Frames used: {report['frames_used']} (skipped: {report['frames_skipped']})", ""]
    lines += _continued_lines(report.get("continued"))
    # the map against its network at the same pixels first; the 3D map and the network alone each on their own
    at_pixels = iou_at_pixels(report)  # what the IoU plot shows
    lines += _pixel_summary(report)
    lines += _pixel_section(report)
    lines += _plot(plots, "iou", "IoU per class, map vs network at the same pixels") if at_pixels else []
    lines += _voxel_section(report)
    lines += [] if at_pixels else _plot(plots, "iou", f"IoU per class, {VOXELS_3D}")
    lines += _network_section(report)
    lines += _map_view_section(map_view)
    sizes = report["bytes_on_disk"]
    lines += ["## Storage", "", "| representation | size | bytes |", "|---|---|---|"]
    if "dense_point_cloud_bytes" in report:
        points, cell = report.get("dense_point_cloud_points"), report.get("dense_point_cloud_cell_m")
        what = (f"{points:,} points, " if points is not None else "") + (f"one per {cell:g} m cell of "
                                                                         if cell is not None else "")
        lines.append(f"| dense coloured point cloud (cloud.ply, binary PLY: {what}every frame's points) | "
                     f"{_kb(report['dense_point_cloud_bytes'])} | {report['dense_point_cloud_bytes']:,} |")
    for name, what in _FILES:
        if name in sizes:
            lines.append(f"| {what} | {_kb(sizes[name])} | {sizes[name]:,} |")
    lines += [f"| in memory ({report['bytes_per_voxel_in_memory']} B per voxel) | {_kb(report['bytes_in_memory'])} | "
              f"{report['bytes_in_memory']:,} |",
              "", _counts_line(report), "",
              *_plot(plots, "storage", "storage per representation")]
    if "maps" in report:
        lines += _maps_section(report["maps"])
    if "objects" in report:
        lines += _objects_section(report["objects"])
    lines += ["## Timings (ms per frame)", "", "| stage | ms |", "|---|---|"]
    lines += [f"| {k} | {v:.2f} |" for k, v in report["ms_per_frame"].items()]
    lines += ["", *_plot(plots, "timings", "time per stage")]
    if plots and "trajectory" in plots:
        traj = report.get("trajectory_vs_ground_truth")
        lines += ["## Trajectory", "", f"Poses: `{report.get('poses', '?')}`" + (
            f"; against ground truth ATE {100 * traj['ate_rmse_m']:.2f} cm, RPE {100 * traj['rpe_trans_m']:.2f} cm "
            f"per frame ({traj['matched']} poses)." if traj else "."), "", *_plot(plots, "trajectory", "trajectory")]
    lines += ["![preview](preview.png)", ""]
    lines += [f"![{kind}](preview_{kind}.png)" for kind in list(report.get("maps", {}))[1:]]
    if "maps" in report:
        lines.append("")
    return "\n".join(lines)


def _map_view_section(shown: ViewContent | None) -> list[str]:
    """Where report.html shows the map in 3D, what it draws and what it left out."""
    if shown is None:
        return []
    what = [f"{shown.drawn:,} voxels in {len(shown.classes)} classes" if shown.classes != ("voxels",)
            else f"{shown.drawn:,} voxels"]
    what += [f"{shown.objects} object boxes" if shown.objects else "", "the camera path" if shown.poses else ""]
    return ["## The map in 3D", "",
            f"`report.html` shows the map here to turn and zoom ({', '.join(w for w in what if w)}): a click on a "
            "class in the legend hides or shows it, a double click shows it alone, and `RGB` switches to the "
            "observed colours. `semmap view MAP --html FILE` writes the same view for any map file."
            + (f" {shown.note[0].upper()}{shown.note[1:]}." if shown.note else ""), "", MAP_VIEW_MARKER, ""]


def _realism_line(report: dict) -> list[str]:
    """Simulated frames: the realism preset they were rendered with, in words."""
    if "realism" not in report:
        return []
    from semmap.sim.realism import SUMMARIES

    what = SUMMARIES.get(report["realism"])
    return [f"Realism: `{report['realism']}`" + (f" ({what})" if what else "") + "  "]


def _voxel_section(report: dict) -> list[str]:
    """The 3D map scored on its own against the ground-truth voxels, geometry beside it, and its IoU per class;
    without a segmenter, what its classes came from (ground-truth labels score fusion and geometry only)."""
    if "miou_3d" not in report:
        return _alignment_lines(report)
    lines = [f"## {VOXELS_3D}", ""]
    if segmenter_of(report) is None and "semantics" in report:
        lines += [f"No segmenter ran (semantics: {report['semantics']}): these scores measure the fusion and the "
                  "geometry, not a segmenter.", ""]
    rows = (("mIoU", "miou_3d"), ("voxel accuracy", "voxel_accuracy_3d"), ("MPA", "mpa_3d"),
            ("geometric precision", "geometric_precision_3d"), ("coverage", "gt_coverage_3d"))
    lines += [f"| measure | {VOXELS_3D} |", "|---|---|",
              *(f"| {name} | {_cell(report[key], key)} |" for name, key in rows if key in report), "",
              f"Occupied voxels matched to ground-truth surface voxels within one voxel; geometric precision: the "
              f"share of occupied voxels on a true surface; coverage: the share of the {report['gt_voxels']:,} "
              "ground-truth surface voxels the map holds. Every voxel counts once, however often it was seen: this "
              "is not comparable with a per-pixel MIoU.", "", *_alignment_lines(report)]
    per3 = report.get("per_class_iou_3d", {})
    lines += ["| class | IoU, 3D map vs ground-truth voxels |", "|---|---|",
              *(f"| {name} | {iou:.3f} |" for name, iou in sorted(per3.items(), key=lambda kv: -kv[1]))]
    return [*lines, ""]


def _network_section(report: dict) -> list[str]:
    """The network's own per-frame scores over every labelled pixel it segmented, and its IoU per class."""
    seg = segmenter_of(report)
    if seg is None:
        return []
    rows = (("MIoU", "miou_2d"), ("pixel accuracy", "pixel_accuracy_2d"), ("MPA", "mpa_2d"))
    lines = [f"## The network alone ({seg}), every labelled pixel", "",
             f"Each frame's segmentation against its true labels over every labelled pixel of the "
             f"{report.get('frames_segmented', '?')} frames segmented (for the map against it, see the same pixels "
             "above).", "", f"| measure | {seg}, every labelled pixel |", "|---|---|",
             *(f"| {name} | {report[f'{seg}_{key}']:.3f} |" for name, key in rows if f"{seg}_{key}" in report), ""]
    per2 = report.get(f"{seg}_per_class_iou_2d", {})
    if per2:
        lines += [f"| class | IoU, {seg} per frame |", "|---|---|",
                  *(f"| {name} | {iou:.3f} |" for name, iou in sorted(per2.items(), key=lambda kv: -kv[1])), ""]
    return lines


def _cell(value: float, key: str) -> str:
    """A score to three places, the map's mIoU in bold."""
    return f"**{value:.3f}**" if key == "miou_3d" else f"{value:.3f}"


_FILES = (("map.bt", "OctoMap .bt (occupancy only)"), ("map.ot", "semantic OctoMap .ot (ColorOcTree)"),
          ("map.semmap", "native map (log-odds, colour, top-3 distribution)"),
          ("voxelgrid.semmap", "semantic voxel grid, native (every voxel's class state)"),
          ("voxelgrid.ply", "semantic voxel grid, binary PLY (occupied voxels)"),
          ("points.semmap", "semantic point map, native"), ("points.ply", "semantic point map, binary PLY"))


def _pixel_summary(report: dict) -> list[str]:
    """The line a reader reads first: whether the map labels the frames' pixels better than the network."""
    if "pixel_gain" not in report:
        return []
    gain = 100 * report["pixel_gain"]
    verdict = "better than" if gain > 0 else ("as good as" if gain == 0 else "worse than")
    return [f"**At the same pixels the map labels {verdict} the network: MIoU {report['pixel_miou_map']:.3f} "
            f"against {report['pixel_miou_network']:.3f} ({gain:+.1f} points), on "
            f"{100 * report['pixel_coverage']:.0f} % of the labelled pixels of every {report['pixel_every']}th "
            "frame.**", ""]


def _pixel_section(report: dict) -> list[str]:
    """The table "network vs map at the same pixels": final map, causal map, and the fusion ceiling."""
    if "pixel_miou_map" not in report:
        return []
    net = "pixel_miou_network" in report

    def row(name: str, suffix: str) -> str:
        cells = [f"{report.get(f'pixel_{m}_map{suffix}', float('nan')):.3f}" for m in ("miou", "accuracy", "mpa")]
        if net:
            cells += [f"{report.get(f'pixel_{m}_network{suffix}', float('nan')):.3f}"
                      for m in ("miou", "accuracy", "mpa")]
            cells.append(f"{100 * report.get(f'pixel_gain{suffix}', float('nan')):+.1f}")
        return f"| {name} | " + " | ".join(cells) + f" | {report.get(f'pixel_coverage{suffix}', float('nan')):.3f} |"

    head = "| map | mIoU | accuracy | MPA |" + (" network mIoU | accuracy | MPA | gain (points) |" if net else "")
    lines = [f"## {SAME_PIXELS[0].upper()}{SAME_PIXELS[1:]}", "", head + " coverage |",
             "|---" * head.count("|") + "|", row("final", ""), row("causal (as the frame arrived)", "_causal"),
             "", f"Every {report['pixel_every']}th frame ({report['pixel_frames']} frames, every "
             f"{report['pixel_stride']}th pixel row and column): each pixel's depth back-projected with the frame's "
             "pose, the map's label at that point against the true label, on exactly the pixels where "
             + ("both the map and the network give a label." if net else "the map gives a label (no network).")]
    if "ceiling_voxel_accuracy" in report:
        lines.append(f"Ceiling: over the {report['ceiling_voxels']:,} voxels these pixels fall into, the network's "
                     f"plurality label is right in {100 * report['ceiling_voxel_accuracy']:.1f} %, and in "
                     f"{100 * report['unreachable_share']:.1f} % the true class is never among its labels (no "
                     "per-voxel rule can get those right).")
    return [*lines, ""]


def _alignment_lines(report: dict) -> list[str]:
    """Where the map built from estimated poses was scored: the transform onto the ground truth and its source."""
    a = report.get("map_alignment")
    if a is None:
        return []
    if "T_gt_map" not in a:
        return [f"The map built from `{report.get('poses', '?')}` poses could not be aligned to the ground truth "
                f"({a.get('why', '?')}): it is not scored in 3D.", ""]
    T = np.asarray(a["T_gt_map"], np.float64)
    angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1.0, 1.0)))
    return [f"The map was built from `{report.get('poses', '?')}` poses, in their frame; 3D scores and the trajectory "
            f"plot move it onto the ground truth by the {a['method']} ({a['frames']} frames, as the ATE): a rotation "
            f"of {angle:.2f}° and a translation of {np.linalg.norm(T[:3, 3]):.3f} m (`map_alignment` in report.json).",
            ""]


def _counts_line(report: dict) -> str:
    """What the primary map holds: the OctoMap's voxels and pruned leaves, or a voxel grid's / point map's size."""
    if "occupied_leaves" in report:
        return (f"Occupied voxels: {report['occupied_voxels']:,}, free voxels: {report['free_voxels']:,}; "
                f"after pruning: {report['occupied_leaves']:,} occupied and {report['free_leaves']:,} free leaves.")
    if "points" in report:
        return f"Points: {report['points']:,} (from {report['keyframes_integrated']} keyframes)."
    return f"Voxels: {report['voxels']:,}, occupied: {report['occupied_voxels']:,}."


def _objects_section(o: dict) -> list[str]:
    """The object map: counts, its accuracy when there was ground truth, and a table of the objects."""
    rule = o.get("kept_if_at_least", {"frames_seen": 3, "sightings": 2})
    lines = ["## Objects", "",
             f"{o['objects']} objects, each tracked in at least {rule['frames_seen']} frames and mapped from at least "
             f"{rule['sightings']} keyframes ({o['candidates']} candidates seen less), from `{o['instance_source']}` "
             f"instances over {o['keyframes']} keyframes"
             + "".join(f"{': ' if i == 0 else ', '}{n} {c}" for i, (c, n) in enumerate(o["per_class"].items())) + ".",
             "",
             f"Points: {o['points_in_masks']:,} in the masks, {o['points_after_outlier_removal']:,} after outlier "
             f"removal, {o['points_in_objects']:,} in the objects after the voxel filter. Tracking "
             f"{o['ms_per_frame']['tracking']:.1f} ms per frame, the object map {o['ms_per_keyframe']:.1f} ms per "
             "keyframe.", ""]
    if "count_error" in o:
        lines += [f"Against ground truth: object count error {100 * o['count_error']:.1f} % over all classes "
                  f"({o['objects_ground_truth']} objects visible; eq. 24 on the totals "
                  f"{100 * o['count_error_eq24']:.1f} %), {o['id_switches']} identity switches.", ""]
    lines += ["| id | class | confidence | centroid (m) | points | frames tracked | keyframes |",
              "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['id']} | {r['class']} | {r['confidence']:.2f} | "
              f"{', '.join(f'{c:.2f}' for c in r['centroid'])} | {r['points']:,} | "
              f"{r.get('frames_seen', r['sightings'])} | {r['sightings']} |" for r in o["table"]]
    if len(o["table"]) < o["objects"]:
        lines.append(f"| … | {o['objects'] - len(o['table'])} more in objects.json | | | | | |")
    return [*lines, ""]


def _maps_section(maps: dict) -> list[str]:
    """The maps of the run side by side: fusion, size, accuracy (before / after the CRF), storage."""
    lines = ["## Maps side by side", "",
             "| map | fusion | elements | MIoU at the same pixels | 3D mIoU vs ground-truth voxels | before CRF | "
             "voxel accuracy | MPA | geometric precision | coverage | B per element in memory | files |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for kind, m in maps.items():
        size = m.get("points", m.get("voxels", m.get("occupied_voxels", 0) + (m.get("free_voxels") or 0)))
        before = m.get("crf", {}).get("miou_3d_before")
        files = ", ".join(f"{name} {_kb(n)}" for name, n in m.get("files", {}).items() if not name.endswith(".png"))

        def fmt(key: str, m: dict = m) -> str:
            return f"{m[key]:.3f}" if key in m else "–"

        lines.append(f"| {kind} | {m.get('fusion', '–')} | {size:,} | {fmt('pixel_miou_map')} | {fmt('miou_3d')} | "
                     f"{'–' if before is None else f'{before:.3f}'} | {fmt('voxel_accuracy_3d')} | {fmt('mpa_3d')} | "
                     f"{fmt('geometric_precision_3d')} | {fmt('gt_coverage_3d')} | "
                     f"{m['bytes_per_voxel_in_memory']} | {files} |")
    return [*lines, "", "All maps are scored at the same pixels and on the same ground-truth voxels (a finer point "
            "map votes per voxel).", ""]


def write_report_md(path: str | Path, report: dict, *, title: str = "semmap run",
                    plots: dict[str, str] | None = None, map_view: ViewContent | None = None) -> Path:
    return write_text_atomic(path, render_report_md(report, title=title, plots=plots, map_view=map_view))
