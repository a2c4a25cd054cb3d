"""The evaluation family: ``semmap eval-traj`` (trajectories), ``eval-seg`` (label images) and ``eval-map`` (a map at
a labelled sequence's pixels or a dataset's labelled points)."""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Annotated

import typer

from semmap.cli.options import FORMATS_HELP, Json
from semmap.cli.terminal import cm, setup_logging, sim3_scale, summary_out
from semmap.datasets import AUTO
from semmap.perception.registry import SEGMENTERS


def eval_traj(
    gt: Annotated[Path, typer.Argument(help="reference: a TUM trajectory file, or a dataset folder with poses")],
    est: Annotated[list[Path], typer.Argument(help="estimated trajectories (TUM format); several are compared")],
    max_time_diff: Annotated[float, typer.Option(help="largest timestamp difference of matched poses (s)")] = 0.02,
    plot: Annotated[Path | None, typer.Option(help="write a trajectory plot PNG here")] = None,
    pairwise: Annotated[bool, typer.Option("--pairwise", help="also the ATE between every two estimates and the "
                                           "error they share")] = False,
    reference2: Annotated[Path | None, typer.Option(help="a second, independent reference (TUM file or dataset "
                                                    "folder): every trajectory is scored against it too")] = None,
    rotation_frames: Annotated[int | None, typer.Option(help="also compare relative rotations over N frames "
                                                        "between every two trajectories (no alignment needed)")
                               ] = None,
    plot_errors: Annotated[Path | None, typer.Option(help="write each estimate's position error per axis over the "
                                                     "frames to this PNG")] = None,
    as_json: Json = False,
) -> None:
    """ATE (after SE(3) Umeyama alignment) and RPE of estimated trajectories against a reference; with several
    estimates, `--pairwise` or `--reference2`, a comparison of all of them."""
    setup_logging(False)
    from semmap.runner import evaluate_trajectories

    scores = evaluate_trajectories(gt, est, max_time_diff=max_time_diff, pairwise=pairwise, reference2=reference2,
                                   rotation_frames=rotation_frames, plot=plot, plot_errors=plot_errors)
    rows = _traj_rows(scores) + [(what, str(path)) for what, path in (("plot", plot), ("error plot", plot_errors))
                                 if path is not None]
    summary_out(scores, as_json, f"semmap eval-traj: against {gt}", rows)


def _traj_rows(scores: dict) -> list[tuple[str, str]]:
    """``semmap eval-traj``'s table: ATE, RPE and scale per estimate, then the comparisons asked for."""
    def scored(s: dict) -> str:
        return (f"ATE {cm(s['ate_rmse_m'])}, RPE {cm(s['rpe_trans_m'])} / {s['rpe_rot_deg']:.2f}° per frame, "
                f"Sim(3) scale {sim3_scale(s['sim3_scale'])}, {s['matched']} poses matched")

    if "estimates" not in scores:
        s = scores
        return [("ATE (SE(3) aligned)", cm(s["ate_rmse_m"])),
                ("ATE mean / median / max", " / ".join(cm(s[k]) for k in ("ate_mean_m", "ate_median_m",
                                                                          "ate_max_m"))),
                ("RPE per frame", f"{cm(s['rpe_trans_m'])}, {s['rpe_rot_deg']:.2f}°"),
                ("Sim(3) scale", sim3_scale(s["sim3_scale"])),
                ("poses matched", f"{s['matched']} (reference {s['gt_poses']}, estimate {s['est_poses']})"),
                ("ground-truth path", f"{s['gt_path_length_m']:.2f} m")]
    rows = [(name, scored(s)) for name, s in scores["estimates"].items()]
    rows += [(f"{a} vs {b}", f"{cm(p['ate_m'])} apart, {cm(p['shared_m'])} of error shared")
             for p in scores.get("pairwise", []) for a, b in [p["between"]]]
    rows += [(f"{name} vs --reference2", f"ATE {cm(s['ate_rmse_m'])}, {s['matched']} poses matched")
             for name, s in scores.get("reference2", {}).items()]
    if "rotation_disagreement_deg" in scores:
        r = scores["rotation_disagreement_deg"]
        rows.append((f"rotation over {r['frames']} frames", f"{r['common_frames']} common frames; the matrix of "
                                                          f"{', '.join(r['order'])} with --json"))
    return rows


def eval_seg(
    pred_dir: Annotated[Path, typer.Argument(metavar="PRED_DIR|SEQ", help="folder of predicted label PNGs (class "
                                             "ids); with --segmenter the labelled frames: any sequence semmap "
                                             "reads, or still frames (rgb/ depth/ labels/, NYU-40)")],
    gt_dir: Annotated[Path | None, typer.Argument(help="folder of ground-truth label PNGs with the same names "
                                                       "(without --segmenter)")] = None,
    num_classes: Annotated[int | None, typer.Option(help="number of classes K (ids 0..K-1); default: the label "
                                                        "set's, else the largest id in the images + 1")] = None,
    labelset: Annotated[Path | None, typer.Option(help="labelset.json naming the classes (default: the one in or "
                                                       "beside GT_DIR, as semmap simulate writes it)")] = None,
    ignore: Annotated[int, typer.Option(help="ground-truth id left out (255: VOC boundaries; -1: none)")] = 255,
    out: Annotated[Path | None, typer.Option(help="also write the scores as JSON here")] = None,
    resize: Annotated[bool, typer.Option("--resize", help="resize predictions of another size than their ground "
                                         "truth (nearest neighbour) instead of refusing them")] = False,
    segmenter: Annotated[str | None, typer.Option(help="run this segmenter over SEQ and score it in NYU-40 over the "
                                                  f"classes both name ({SEGMENTERS.choices()}, NAME+structure)")
                         ] = None,
    weights: Annotated[Path | None, typer.Option(help="--segmenter's weights (default: the shipped ones)")] = None,
    labels: Annotated[Path | None, typer.Option(help="SEQ's label PNGs, when they are not in it")] = None,
    gt_classes: Annotated[str | None, typer.Option(help="the labels' classes: nyu40 | semmap (default: semmap for "
                                                   "the simulator's label set, else nyu40)")] = None,
    every: Annotated[int, typer.Option(help="--segmenter: score every N-th frame")] = 1,
    max_frames: Annotated[int | None, typer.Option(help="--segmenter: read at most N frames")] = None,
    up: Annotated[str | None, typer.Option(help="--segmenter NAME+structure: the world's up axis (+z, ...), "
                                                "else from the frames")] = None,
    as_json: Json = False,
) -> None:
    """Segmentation accuracy of predicted label images: MIoU and MPA (eqs. 11-12), per-class IoU and accuracy,
    confusion matrix; with --segmenter, of a segmenter run over labelled (real) frames, in NYU-40."""
    setup_logging(False)
    if segmenter is not None:
        _eval_segmenter(pred_dir, segmenter, weights=weights, labels=labels, gt_classes=gt_classes, every=every,
                        max_frames=max_frames, up=up, out=out, as_json=as_json)
        return
    from semmap.errors import ConfigError
    from semmap.eval.segmentation import evaluate_label_folders

    if gt_dir is None:
        raise ConfigError("eval-seg: give GT_DIR (the ground-truth label PNGs), or --segmenter NAME to run one over "
                          f"the labelled frames in {pred_dir}")
    result = evaluate_label_folders(pred_dir, gt_dir, num_classes, ignore=None if ignore < 0 else ignore,
                                    resize=resize, out=out, label_set=labelset)
    d = result.to_dict()
    classes = (f"{result.num_classes} from {result.label_set_path}" if result.label_set_path is not None
               else f"{result.num_classes} (ids 0..{result.num_classes - 1}, no labelset.json)")
    rows = [("images", f"{d['images']} scored, {len(d['missing_predictions'])} without a prediction"),
            ("classes", classes), *((name, "-" if d[k] is None else f"{d[k]:.4f}") for k, name in
                                    (("miou", "mIoU"), ("mpa", "MPA"), ("pixel_accuracy", "pixel accuracy")))]
    rows += [(f"IoU {name}", f"{'-' if c['iou'] is None else format(c['iou'], '.4f')} (accuracy "
                             f"{'-' if c['accuracy'] is None else format(c['accuracy'], '.4f')}, {c['pixels']:,} px)")
             for name, c in d["per_class"].items()]
    if out is not None:
        rows.append(("scores written to", str(out)))
    summary_out(d, as_json, f"semmap eval-seg: {pred_dir} against {gt_dir}", rows)


def _eval_segmenter(seq: Path, segmenter: str, *, out: Path | None, as_json: bool, **options) -> None:
    """``eval-seg SEQ --segmenter NAME``: the segmenter over the frames, in NYU-40, as a table or JSON."""
    from semmap.cli.terminal import progress_bar
    from semmap.run.eval_seg import score_on_frames

    scores = score_on_frames(seq, segmenter, out=out, progress=progress_bar("segmenting"), **options)
    d = scores.to_dict()
    rows = [("frames", str(d["frames"])),
            ("mIoU (NYU-40)", "-" if d["miou"] is None else f"{d['miou']:.4f} over {len(d['classes'])} classes "
                                                              "both name"),
            ("pixel accuracy", "-" if d["pixel_accuracy"] is None else f"{d['pixel_accuracy']:.4f}")]
    rows += [(f"IoU {name}", f"{c['iou']:.4f} ({c['pixels']:,} px)") for name, c in d["per_class"].items()]
    if out is not None:
        rows.append(("scores written to", str(out)))
    summary_out(d, as_json, f"semmap eval-seg: {segmenter} on {seq}", rows)


def eval_map(
    map_path: Annotated[Path, typer.Argument(metavar="MAP", help="a .semmap map file (any map), or a run folder "
                                             "holding map.semmap")],
    seq: Annotated[Path | None, typer.Argument(help="the labelled sequence it was built from (poses and label "
                                                    "images); may be left out with --gt-ply")] = None,
    format: Annotated[str, typer.Option(help=FORMATS_HELP)] = AUTO,
    segmenter: Annotated[str | None, typer.Option(help="score this network's labels at the same pixels beside the "
                                                  "map's (precomputed --weights FOLDER: stored predictions); "
                                                  f"none: the map alone. {SEGMENTERS.choices()}")] = None,
    weights: Annotated[Path | None, typer.Option(help="segmenter weights, or the folder of predictions")] = None,
    every: Annotated[int, typer.Option(help="score every N-th frame")] = 10,
    pixel_stride: Annotated[int, typer.Option(help="score every k-th pixel row and column")] = 1,
    max_frames: Annotated[int | None, typer.Option(help="read at most N frames")] = None,
    gt_ply: Annotated[Path | None, typer.Option(help="labelled ground-truth points or mesh vertices (PLY, e.g. "
                                                "ScanNet's *_vh_clean_2.labels.ply): mIoU, f.w. mIoU and mean class "
                                                "accuracy over them, in the map's class ids")] = None,
    gt_label_property: Annotated[str, typer.Option(help="the vertex property of --gt-ply holding the class")
                                 ] = "label",
    out: Annotated[Path | None, typer.Option(help="also write the scores as JSON here")] = None,
) -> None:
    """A map scored at the pixels of a labelled sequence: the map's label at each pixel's 3D point against the true
    label, beside the network's own label at the same pixels (MIoU, accuracy, MPA, coverage, the fusion ceiling);
    with --gt-ply, at a dataset's labelled points or mesh vertices as the benchmarks score maps."""
    setup_logging(False)
    from semmap.errors import ConfigError
    from semmap.run.eval_map import evaluate_map_file, evaluate_map_points

    if seq is None and gt_ply is None:
        raise ConfigError("eval-map needs the labelled sequence SEQ, or --gt-ply, or both")
    pixels = functools.partial(evaluate_map_file, map_path, seq, format=format, segmenter=segmenter, weights=weights,
                               every=every, stride=pixel_stride, max_frames=max_frames)
    points = functools.partial(evaluate_map_points, map_path, gt_ply, label_property=gt_label_property)
    if gt_ply is None:
        scores = pixels(out=out)
    elif seq is None:
        scores = points(out=out)
    else:  # both: one JSON of both, its --out checked against every input first
        from semmap.files.atomic import write_text_atomic
        from semmap.files.outputs import OutputKind, check_outputs

        check_outputs([("--out", out, OutputKind.FILE)], [("MAP", map_path), ("SEQ", seq), ("--gt-ply", gt_ply)])
        scores = {**points(out=None), **pixels(out=None)}
        if out is not None:
            write_text_atomic(out, json.dumps(scores, indent=2))
    typer.echo(json.dumps(scores, indent=2))
