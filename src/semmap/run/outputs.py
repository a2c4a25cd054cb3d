"""What a run writes after its frame loop, into the staging folder: every map's files, the object map, the
previews and the configuration; the 3D CRF over the finished maps; and why a map came out empty."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from semmap.config import RunConfig
from semmap.eval.run_report import RunScorer
from semmap.files.atomic import write_text_atomic
from semmap.fusion.crf import CrfParams
from semmap.io.map_files import save_map_files
from semmap.io.ply import write_colored_cloud_ply
from semmap.keys import TREE_MAX_VAL
from semmap.limits import MemoryBudgetError
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MapKind
from semmap.maps.semantic_grid import SemanticGrid
from semmap.object_stage import ObjectStage
from semmap.viz.preview import render_preview, side_by_side, up_vector, with_class_legend, write_png

log = logging.getLogger("semmap")
#: The run's dense coloured point cloud (every frame's points, one per ``mapping.point_resolution`` cell).
CLOUD_FILE = "cloud.ply"


def write_outputs(out: Path, maps: list[SemanticMap], poses: list[np.ndarray], config: RunConfig,
                  objects: ObjectStage | None, *, cloud: SemanticGrid | None = None
                  ) -> tuple[dict[str, Path], dict[str, int]]:
    """Every map's files, the dense coloured ``cloud.ply`` (``cloud``: the voxel-filtered points of every frame),
    the object map's, the previews (the primary map's ``preview.png`` with the objects beside it;
    ``preview_<kind>.png`` of the others) and ``config.json``; (files by name, bytes by file name)."""
    out.mkdir(parents=True, exist_ok=True)
    sizes: dict[str, int] = {}
    semantic = next((m for m in maps if m.kind != MapKind.TSDF), None)  # labels the TSDF's mesh
    for m in maps:
        sizes.update(save_map_files(m, out, labels_from=semantic if m.kind == MapKind.TSDF else None))
    if cloud is not None:
        a = cloud.arrays()
        sizes[CLOUD_FILE] = write_colored_cloud_ply(out / CLOUD_FILE, cloud.centers(a), a.rgb,
                                                    comment=f"semmap dense coloured cloud, one point per "
                                                            f"{cloud.resolution:g} m cell")
    files = {name: out / name for name in sizes}
    if objects is not None:
        sizes.update(objects.write(out, up_vector(poses)))
        files.update({name: out / name for name in ("objects.json", "objects.ply")})
    if config.output.preview:
        for i, m in enumerate(maps):
            name = "preview.png" if i == 0 else f"preview_{m.kind.value}.png"
            files[name] = out / name
            cloud = m.cloud()
            beside = i == 0 and objects is not None  # the objects with their ids beside it, the legend below both
            image = render_preview(cloud, m.label_set, poses, legend=not beside)
            if beside:
                panel = objects.panel(up_vector(poses), size=image.shape[0] - 28)
                image = side_by_side([image, panel], ["", "objects (top-down): id class"])
                image = with_class_legend(image, cloud.labels, m.label_set)
            sizes[name] = write_png(files[name], image)
    write_text_atomic(out / "config.json", config.to_json())
    files["config"] = out / "config.json"
    return files, sizes


def refine_maps(maps: list[SemanticMap], poses: list[np.ndarray], *, params: CrfParams,
                scorer: RunScorer) -> dict[MapKind, dict]:
    """3D dense CRF (``params``: ``--crf-params``) over every map with class distributions; per map: its accuracy
    before (when there is ground truth), elements refined and changed, milliseconds."""
    from semmap.fusion.crf import refine_map

    viewpoint = np.mean([np.asarray(T)[:3, 3] for T in poses], axis=0) if poses else None
    out: dict[MapKind, dict] = {}
    for m in maps:
        if m.label_set is None:
            continue
        before = scorer.map_3d(m)
        try:
            r = refine_map(m, params, viewpoint=viewpoint)
        except MemoryBudgetError as exc:  # a refinement is not worth the map: kept as fused, with a warning
            log.warning("the %s map is not refined: %s", m.kind.value, exc)
            out[m.kind] = {"refined": 0, "changed": 0, "ms": 0.0, "skipped": str(exc)}
            continue
        out[m.kind] = {**({"miou_3d_before": before["miou_3d"],
                           "voxel_accuracy_3d_before": before["voxel_accuracy_3d"]} if before else {}),
                       "refined": r.refined, "changed": r.changed, "ms": round(r.ms, 1)}
    return out


def warn_if_empty(primary: SemanticMap, config: RunConfig, points_integrated: int, poses: list[np.ndarray]) -> None:
    """A run whose frames added nothing to the map says so, with the likely reason."""
    if len(primary.cloud()):
        return
    m = config.mapping
    reasons = []
    reach = TREE_MAX_VAL * m.resolution
    far = max((float(np.abs(np.asarray(T)[:3, 3]).max()) for T in poses), default=0.0)
    if far >= reach:
        reasons.append(f"camera poses lie up to {far:,.0f} m from the origin, beyond the ±{reach:,.0f} m a map of "
                       f"resolution {m.resolution} m can hold")
    if points_integrated == 0:
        reasons.append(f"no depth pixel lies between --min-depth {m.min_depth} and --max-depth {m.max_depth} m")
    if 0 <= m.max_range < m.resolution:
        reasons.append(f"--max-range {m.max_range} m leaves every reading beyond range")
    cut = getattr(primary, "range_cut_m", None) or getattr(getattr(primary, "geometry", None), "range_cut_m", None)
    if cut is not None:
        reasons.append(f"--resolution {m.resolution:g} m is too fine for the scans' range: readings beyond {cut:.2f} m "
                       "were cut off; choose a coarser --resolution")
    log.warning("%d frames added nothing to the map: no voxel is occupied (%s)", len(poses),
                "; ".join(reasons) or "check the poses and depth units")
