"""A run's accuracy in the order it should be read, each figure named by what it measures.

A map's voxel mIoU and its network's pixel MIoU are different units (every voxel counts once, a pixel counts as
often as it is seen), so they are never put side by side: the map is first compared with its network at the same
pixels (:mod:`semmap.eval.pixels`), then the 3D map is scored on its own against the ground-truth voxels, with the
geometry beside it, and the network's own per-frame score comes last, alone. The CLI summary, ``report.md``,
``report.html`` and the README's headline (``benchmarks/update_docs.py``) all take their words from here.
"""

from __future__ import annotations

#: What each figure is called wherever a run's accuracy is shown.
SAME_PIXELS = "map vs network at the same pixels"
VOXELS_3D = "3D map vs ground-truth voxels"
NETWORK_ALONE = "network alone, every labelled pixel"


def segmenter_of(report: dict) -> str | None:
    """The name of the segmenter whose per-frame scores the report holds (``<name>_miou_2d``), or None."""
    return next((k[: -len("_miou_2d")] for k in report if k.endswith("_miou_2d")), None)


def same_pixels(report: dict) -> str | None:
    """The map's MIoU against its network's at the same pixels, the gain and the pixels it covers; None without."""
    if "pixel_miou_map" not in report:
        return None
    every = int(report["pixel_every"])
    frames = "every frame" if every == 1 else f"every {every}th frame"
    where = f"{100 * report['pixel_coverage']:.0f} % of the labelled pixels of {frames}"
    if "pixel_miou_network" not in report:
        return f"map MIoU {report['pixel_miou_map']:.3f} (no network), on {where}"
    seg = report.get("segmenter") or segmenter_of(report) or "network"
    return (f"map MIoU {report['pixel_miou_map']:.3f} vs {seg} {report['pixel_miou_network']:.3f} "
            f"({100 * report['pixel_gain']:+.1f} points), on {where}")


def voxels_3d(report: dict) -> str | None:
    """The 3D map's voxel mIoU with its geometric precision and coverage beside it; None without ground truth."""
    if "miou_3d" not in report:
        return None
    return (f"mIoU {report['miou_3d']:.3f}, geometric precision {report['geometric_precision_3d']:.3f}, "
            f"coverage {report['gt_coverage_3d']:.3f}")


def network_alone(report: dict) -> str | None:
    """The network's own MIoU over every labelled pixel of the frames it segmented; None without one."""
    seg = segmenter_of(report)
    if seg is None:
        return None
    frames = report.get("frames_segmented")
    return f"{seg} MIoU {report[f'{seg}_miou_2d']:.3f}" + (f" over {frames} frames" if frames is not None else "")


def accuracy_rows(report: dict) -> list[tuple[str, str]]:
    """(name, figure) rows in reading order: same pixels first, the 3D map second, the network alone last."""
    rows = [(SAME_PIXELS, same_pixels(report)), (VOXELS_3D, voxels_3d(report)),
            (NETWORK_ALONE, network_alone(report))]
    return [(name, text) for name, text in rows if text is not None]
