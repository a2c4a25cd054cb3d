"""Run every benchmark and the demo, then write docs/BENCHMARKS.md (every number) and README.md's headline table.

    python benchmarks/update_docs.py [--quick] [--only fusion,demo,...|none] [--results FILE]

``--only`` re-runs the named parts (octree, sim, tracking, segmenters, fusion, demo, end_to_end, localization,
networks, products, adapt; ``none``: nothing) and takes the others' results from ``--results`` (a JSON object of part
results, e.g. ``{"fusion": <bench_fusion.py's last line>}``) or else from the JSON block at the end of
docs/BENCHMARKS.md.
Without demo results the docs keep their current demo lines. ``--only none`` re-renders both files from the saved
results alone and keeps the date and machine they were measured on.

docs/BENCHMARKS.md also carries, unchanged from one run to the next, the section between ``KEPT_START`` and
``KEPT_END``: numbers printed by benchmarks this script does not run (bench_objects, bench_batch, bench_memory),
each naming its command.

Each benchmark runs as its own process and its last stdout line (one JSON object) is parsed, so the numbers in
the docs are exactly what the scripts printed on this machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from semmap.eval import headline

ROOT = Path(__file__).resolve().parents[1]
START, END = "<!-- headline:start (written by benchmarks/update_docs.py) -->", "<!-- headline:end -->"
KEPT_START = "<!-- kept:start (copied from the named scripts' output; update_docs.py keeps it as it is) -->"
KEPT_END = "<!-- kept:end -->"
#: the README's headline table holds at most this many rows
HEADLINE_ROWS = 10


def run_json(args: list[str]) -> dict:
    t = time.perf_counter()
    out = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["_seconds"] = round(time.perf_counter() - t, 1)
    return result


def run_demo(out_dir: Path) -> dict:
    """``semmap demo --cloud``: the dense cloud too, for the storage table (``make demo`` writes none; its time is
    the run's without the ``cloud`` stage, :func:`demo_ms`)."""
    subprocess.run([sys.executable, "-m", "semmap.cli", "demo", "--out", str(out_dir), "--cloud"], cwd=ROOT,
                   check=True, capture_output=True)
    return json.loads((out_dir / "report.json").read_text())


def demo_ms(report: dict) -> float:
    """Milliseconds per frame of ``make demo``, which writes no dense cloud: the run's total without its ``cloud``
    stage."""
    ms = report["ms_per_frame"]
    return ms["total"] - ms.get("cloud", 0.0)


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"


def octree_table(bench: dict) -> list[str]:
    rows = ["| resolution | semmap ms/frame | OctoMap ms/frame | ×faster | OctoMap discretized ms/frame | ×faster "
            "| state agreement | semmap B/voxel | OctoMap B/leaf |", "|---|---|---|---|---|---|---|---|---|"]
    for r in bench["results"]:
        rows.append(f"| {r['resolution']} m | {r['semmap_ms']} | {r['octomap_ms']} | **{r['speedup']}** | "
                    f"{r['octomap_discretized_ms']} | **{r['speedup_vs_discretized']}** | "
                    f"{r['agreement']:.4%} | {r['semmap_bytes_per_leaf']} | {r['octomap_bytes_per_leaf']} |")
    return rows


def octree_reference_table(bench: dict) -> list[str]:
    """semmap's full insertion against the occupancy-only yardstick, consecutive and sparse frames (medians)."""
    rows = ["| frames | resolution | semmap ms/frame | occupancy-only ms/frame | ×of the yardstick | state agreement |",
            "|---|---|---|---|---|---|"]
    for case, key in (("consecutive", "results"), (f"every {bench.get('sparse_stride', 50)}th", "sparse_results")):
        for r in bench.get(key, []):
            if "reference_median_ms" not in r:
                continue
            rows.append(f"| {case} | {r['resolution']} m | {r['semmap_median_ms']} | {r['reference_median_ms']} | "
                        f"**{r['vs_reference_median']}** | {r['agreement']:.4%} |")
    return rows


def end_to_end_table(bench: dict) -> list[str]:
    """Frames per second, latency, memory and ATE of online and offline runs (SLAM poses, ESPNetv2 every 5th)."""
    rows = ["| sequence | resolution | mode | frames/s | latency ms (median / p95) | peak MB | ATE cm | "
            "online / offline frames/s |", "|---|---|---|---|---|---|---|---|"]
    for r in bench["results"]:
        lat = r.get("latency_ms")
        ratio = r.get("vs_offline", {}).get("fps", "")
        rows.append(f"| {r['sequence']} | {r['resolution']} m | {r['mode']} | {r['fps']} | "
                    + (f"{lat['median']:.0f} / {lat['p95']:.0f}" if lat else "-")
                    + f" | {r['peak_rss_mb']:.0f} | " + ("-" if r["ate_m"] is None else f"{100 * r['ate_m']:.2f}")
                    + f" | {f'**{ratio}**' if ratio else ''} |")
    return rows


def tracking_table(bench: dict, methods: tuple[str, ...] | None = None, sim3: bool = False) -> list[str]:
    """ATE, RPE and speed per sequence and tracker, with the ATE ratio against the peer on the same sequence
    (``sim3``: also the Sim(3) scale onto the ground truth and the ATE after that fit)."""
    rows = [r for r in bench["results"] if methods is None or r["method"] in methods]
    peer = {r["sequence"]: r["ate_rmse_m"] for r in bench["results"] if r["method"] == bench["peer"]}
    extra_head, extra_rule = (" Sim(3) scale | ATE Sim(3) cm |", "---|---|") if sim3 else ("", "")
    out = [f"| sequence | frames | tracker | ATE cm | RPE cm | ms/frame | ATE / {bench['peer']} |{extra_head}",
           f"|---|---|---|---|---|---|---|{extra_rule}"]
    for r in rows:
        ratio = r["ate_rmse_m"] / peer[r["sequence"]] if r["sequence"] in peer else float("nan")
        extra = (f" {r.get('sim3_scale', float('nan')):.3f} | {100 * r.get('ate_sim3_m', float('nan')):.2f} |"
                 if sim3 else "")
        out.append(f"| {r['sequence']} | {r['frames']} | {r['method']} | {100 * r['ate_rmse_m']:.2f} | "
                   f"{100 * r['rpe_trans_m']:.2f} | {r['ms_per_frame']:.0f} | **{ratio:.2f}** |{extra}")
    return out


def segmenter_table(bench: dict) -> list[str]:
    """CPU time per 640x480 frame (everything a run pays) and of the network alone, per model, input, runtime."""
    out = ["| model | network input | runtime | ms/frame | network ms | start-up s (first run / later) |",
           "|---|---|---|---|---|---|"]
    for r in bench["results"]:
        start = (f"{r['prepare_s']}" + (f" / {r['prepare_cached_s']}" if r.get("prepare_cached_s") else "")
                 if "prepare_s" in r else "-")
        out.append(f"| {r['model']} | {r['input']} | {r['backend']} | {r['ms_per_frame']} | {r['network_ms']} | "
                   f"{start} |")
    return out


def _mean(values) -> float:
    values = list(values)
    return sum(values) / len(values) if values else float("nan")


def fusion_table(bench: dict) -> list[str]:
    """Mean 3D mIoU over the scenes per preset, map and fusion rule, without and with the CRF, with bytes per
    voxel and integration time."""
    rows = bench["results"]
    keys = list(dict.fromkeys((r["preset"], r["map"], r["fusion"]) for r in rows if r["preset"] != "perfect"))
    out = ["| preset | map | fusion | mIoU | + CRF | accuracy | B/voxel | ms/frame |",
           "|---|---|---|---|---|---|---|---|"]
    for preset, kind, fusion in keys:
        sel = [r for r in rows if (r["preset"], r["map"], r["fusion"]) == (preset, kind, fusion)]
        plain, crf = [r for r in sel if not r["crf"]], [r for r in sel if r["crf"]]
        out.append(f"| {preset} | {kind} | {fusion} | {_mean(r['miou'] for r in plain):.3f} | "
                   f"{_mean(r['miou'] for r in crf):.3f} | {_mean(r['accuracy'] for r in plain):.3f} | "
                   f"{_mean(r['bytes_per_voxel'] for r in plain):.0f} | "
                   f"{_mean(r['ms_per_frame'] for r in plain):.1f} |")
    return out


def fusion_targets(bench: dict) -> list[str]:
    """The issue's targets as measured: each a line with the numbers it rests on (means over the scenes)."""
    rows = bench["results"]

    def miou(preset: str, kind: str, fusion: str, crf: bool = False) -> float:
        return _mean(r["miou"] for r in rows if (r["preset"], r["map"], r["fusion"], r["crf"]) ==
                     (preset, kind, fusion, crf))

    def bpv(kind: str, fusion: str) -> float:
        return _mean(r["bytes_per_voxel"] for r in rows if (r["map"], r["fusion"]) == (kind, fusion)
                     and r["preset"] == "cnn-like" and not r["crf"])

    upper = _mean(bench["upper_bound"].values())
    t = bench["timing"]
    crf_gain = [miou("cnn-like", k, f, True) - miou("cnn-like", k, f)
                for k, f in dict.fromkeys((r["map"], r["fusion"]) for r in rows if r["preset"] == "cnn-like")]
    return [
        f"- `independent` preset, fused mIoU / perfect-label upper bound ({upper:.3f}): bayes voxel grid "
        f"{miou('independent', 'voxelgrid', 'bayes') / upper:.1%}, bayes point map "
        f"{miou('independent', 'points', 'bayes') / upper:.1%}, topk OctoMap "
        f"{miou('independent', 'octomap', 'topk') / upper:.1%}, topk voxel grid "
        f"{miou('independent', 'voxelgrid', 'topk') / upper:.1%}.",
        f"- `cnn-like`, {bench['classes']} classes: topk (k = 3) OctoMap {miou('cnn-like', 'octomap', 'topk'):.3f} "
        f"and voxel grid {miou('cnn-like', 'voxelgrid', 'topk'):.3f} against bayes "
        f"{miou('cnn-like', 'voxelgrid', 'bayes'):.3f}; bytes per voxel: topk voxel grid "
        f"{bpv('voxelgrid', 'topk'):.0f} = {bpv('voxelgrid', 'topk') / bpv('voxelgrid', 'bayes'):.0%} of bayes "
        f"({bpv('voxelgrid', 'bayes'):.0f}), OctoMap {bpv('octomap', 'topk'):.0f} = "
        f"{bpv('octomap', 'topk') / bpv('voxelgrid', 'bayes'):.0%}; bayes - max "
        f"{100 * (miou('cnn-like', 'voxelgrid', 'bayes') - miou('cnn-like', 'voxelgrid', 'max')):+.1f} points; "
        f"CRF gain per map and rule {100 * min(crf_gain):+.1f} to {100 * max(crf_gain):+.1f} points.",
        f"- Speed at {t['width']}x{t['height']} ({t['points_per_frame']:,} points per frame, 5 cm, same loop): "
        f"voxel grid K = 40 bayes {t['voxelgrid_bayes_k40_ms']} ms per frame, OctoMap {t['octomap_ms']} ms "
        f"(ratio {t['ratio']}). Memory per voxel: OctoMap {t['octomap_bytes_per_voxel']} B; voxel grid "
        + ", ".join(f"{k.replace('_', ' ')} {v} B" for k, v in t["bytes_per_voxel"].items()) + ".",
    ]


def localization_table(bench: dict) -> list[str]:
    """Convergence, error after convergence and ms per update per model (benchmarks/bench_localization.py)."""
    rows = ["| rooms | initialisation | model | particles | converged | updates to converge | error after "
            "(cm / °) | ms per update (median / best; CPU) |", "|---|---|---|---|---|---|---|---|"]
    for g in bench["summary"]:
        err = "–" if g["median_pos_err_m"] is None else \
            f"{100 * g['median_pos_err_m']:.1f} / {g['median_rot_err_deg']:.2f}"
        rows.append(f"| {g['rooms']} | {g['init']} ({g['mode']}) | {g['model']} | {g['particles']} | "
                    f"{g['converged_rate']:.0%} of {g['runs']} | {g['median_frames_to_converge'] or '–'} | {err} | "
                    f"{g['median_ms_per_update']} / {g['best_ms_per_update']}; "
                    f"{g.get('median_cpu_ms_per_update', '–')} |")
    return rows


def localization_section(bench: dict | None) -> list[str]:
    """The BENCHMARKS.md section on localization (nothing when bench_localization.py has not been run)."""
    if bench is None:
        return []
    return [
        "## Localization in a prior map", "",
        "`benchmarks/bench_localization.py`: simulated rooms (half of them symmetric: geometry identical under a "
        "180° turn, only classes differ) mapped with ground-truth poses, then localized along another path (10 "
        "updates per second of motion, ground truth with 5 % drift as odometry). A run converges when the filter "
        "says so and its median error after that is under 25 cm / 10°; errors are medians over converged runs. The "
        f"paper's per-particle local map costs {bench['peer']['paper_style_ms_per_particle']} ms per "
        "particle in the same run.", "",
        *localization_table(bench), ""]


def products_section(bench: dict | None) -> list[str]:
    """The BENCHMARKS.md section on robot products (nothing when bench_products.py has not been run)."""
    if bench is None:
        return []
    out = ["## Robot products: navigation grid, distance field and semantic mesh", "",
           "`benchmarks/bench_products.py`: the OctoMap of each scene (ground-truth poses), then what `semmap export "
           "grid|esdf` computes. ESDF: semmap's exact transform against scipy's `distance_transform_edt` (signed, "
           "both sides) on the same volume; incremental: the update per frame from the voxels that flipped (the "
           "last frames of the sequence, one after another, 2 m maximum distance) against the full exact transform "
           "of the same frame. Error: largest absolute difference (m). Mesh: semmap's TSDF (`--maps octomap,tsdf`) "
           "meshed by marching cubes and labelled from the OctoMap (the whole step, as `semmap export mesh` runs "
           "it) against Open3D's `VoxelBlockGrid.extract_triangle_mesh` over the same frames (same voxel and "
           "truncation); its error is the share of classified vertices whose class is not that of the OctoMap "
           "voxel they lie in (or the nearest occupied one within a voxel).", "",
           "| scene | product | ms | peer ms | × | error (m) |", "|---|---|---|---|---|---|"]
    for r in bench["results"]:
        ratio = f"{r['peer_ms'] / r['ms']:.1f}" if r.get("peer_ms") else "–"
        err = "–" if r["error"] is None else f"{r['error']:.1e}"
        err += " (share)" if r["product"] == "mesh" and r["error"] is not None else ""
        out.append(f"| {r['scene']} | {r['product']} | {r['ms']} | {r.get('peer_ms') or '–'} | {ratio} | {err} |")
    return [*out, ""]


#: The papers' own numbers beside semmap's network table (CBAM paper Table 2, ADE20K; RGB-D paper Table 3, NYUDv2).
PAPER_NETWORKS = ("CBAM paper, Table 2 (ADE20K, ResNet-50, full size): FCN MPA 69.83 / MIoU 26.23, PSPNet 71.70 / "
                  "30.69, CBAM-PSPNet 74.25 / 32.57. RGB-D paper, Table 3 (NYUDv2): colour only 54.8 / 35.4, "
                  "RGB-D 59.5 / 39.4 (+4.0 MIoU).")


def networks_table(bench: dict, real: dict | None = None) -> list[str]:
    """Test scores and CPU time per 640x480 frame of the shipped networks (ONNX Runtime rows carry the timing); the
    real-frame column from bench_networks.py, else from bench_real.py's row of the same network."""
    yard = {r["segmenter"]: r for r in (real or {}).get("results", [])}
    out = ["| network | input | params | MPA | MIoU | real frames: wall / floor IoU | ms/frame torch | ms/frame ONNX |",
           "|---|---|---|---|---|---|---|---|"]
    rows: dict[str, dict] = {}
    for r in bench["results"]:
        rows.setdefault(r["model"], {})[r["runtime"]] = r
    for model, by in rows.items():
        t = by.get("torch", by.get("onnx"))
        if t.get("miou") is None:
            acc = f"– | shared classes {t['miou_shared']:.3f}"
        else:
            acc = f"{t['mpa']:.3f} | **{t['miou']:.3f}**"
        y = yard.get(model.split("-espnetv2")[0], {})
        wall, floor = t.get("real_wall_iou", y.get("wall")), t.get("real_floor_iou", y.get("floor"))
        real = " / ".join("–" if v is None else f"{v:.3f}" for v in (wall, floor))
        real = "–" if wall is None and floor is None else real
        out.append(f"| {model} | {t['input']} | {t['params'] / 1e6:.2f} M | {acc} | {real} | "
                   f"{by.get('torch', {}).get('ms_per_frame', '–')} | {by.get('onnx', {}).get('ms_per_frame', '–')} |")
    return out


def networks_section(bench: dict | None, real: dict | None = None) -> list[str]:
    """The BENCHMARKS.md section on the trained networks (nothing when bench_networks.py has not been run)."""
    if bench is None:
        return []
    return ["## The papers' networks, trained by semmap", "",
            f"`benchmarks/bench_networks.py`: shipped weights (weights/) on {bench['frames']} held-out simulated "
            f"frames ({', '.join(bench['test_scenes'])}), 640×480, {bench['threads']} CPU threads. "
            "ESPNetv2 (PASCAL VOC) scored on the classes VOC shares with the simulator.", "",
            *networks_table(bench, real), "", PAPER_NETWORKS, ""]


def real_section(bench: dict | None) -> list[str]:
    """The BENCHMARKS.md section on real frames: the redkitchen yardstick per segmenter and the real default's
    kitchen map (nothing when bench_real.py has not been run)."""
    if bench is None:
        return []
    y = bench["yardstick"]
    shares = y["pixel_shares"]

    def pct(v: float | None) -> str:
        return "–" if v is None else f"{v:.3f}"

    out = ["## Real frames: the 7-Scenes redkitchen structure yardstick", "",
           f"`benchmarks/bench_real.py`: wall, floor and ceiling from the planes of the ground-truth-posed map "
           f"(`semmap.eval.room_yardstick`, {len(y['walls'])} walls, floor {'found' if y['floor'] else 'none'}, "
           f"ceiling {'found' if y['ceiling'] else 'not seen'}), rendered into every {y['frames_every']}th frame "
           f"({y['frames']} frames; wall {shares[1]:.1%}, floor {shares[2]:.1%} of the pixels, the rest other "
           f"{shares[4]:.1%} or no depth {shares[0]:.1%}). IoU over the pixels with depth; a segmenter's other "
           "classes count as other.", "",
           "| segmenter | wall IoU | floor IoU | ceiling IoU |", "|---|---|---|---|"]
    out += [f"| {r['segmenter']} | {pct(r['wall'])} | {pct(r['floor'])} | {pct(r['ceiling'])} |"
            for r in bench["results"]]  # its times are left out: measured beside other work, they mislead
    m = bench.get("map")
    if m:
        out += ["", f"The kitchen mapped by `semmap run` with no `--segmenter` ({m['semantics']}, ground-truth poses, "
                f"{m['resolution']} m, {m['frames']} frames): of the {m['floor_plane_voxels']:,} "
                f"voxels on the floor plane {m['floor_plane_labelled_floor']:.1%} are `floor`; of the "
                f"{m['floor_voxels']:,} `floor` voxels {m['floor_voxels_on_plane']:.1%} lie on the floor plane; of the "
                f"{m.get('table_voxels', 0):,} `table` voxels {pct(m.get('table_precision'))} lie on the table top's "
                f"plane ({pct(m.get('table_off_floor'))} off the floor). Largest classes: "
                + ", ".join(f"{k} {v:,}" for k, v in m["largest_classes"].items()) + "."]
    return [*out, ""]


def demo_lines(report: dict) -> list[str]:
    """The demo's lines: the map against its network at the same pixels first, then the 3D map against the
    ground-truth voxels on its own (a voxel mIoU and a pixel MIoU are different units, never one comparison)."""
    sizes = report["bytes_on_disk"]
    ms = report["ms_per_frame"]
    mapping_ms = sum(v for k, v in ms.items() if k not in ("load", "segment", "total", "cloud"))
    seg = report.get("segmenter", "oracle")
    what = ("cnn-like oracle, ~75 % pixel accuracy" if seg == "oracle"
            else f"the shipped {seg} network, trained by semmap on other simulated scenes")
    realism = report.get("realism", "clean")
    return [
        f"- {headline.SAME_PIXELS[0].upper()}{headline.SAME_PIXELS[1:]}: {headline.same_pixels(report)} "
        f"(segmenter: {what}; realism `{realism}`).",
        f"- {headline.VOXELS_3D}: {headline.voxels_3d(report)} (every voxel counts once: not comparable with a "
        "per-pixel MIoU).",
        f"- {headline.NETWORK_ALONE[0].upper()}{headline.NETWORK_ALONE[1:]}: {headline.network_alone(report)}.",
        f"- {report['frames_used']} frames, {demo_ms(report):.0f} ms per frame in all (rendering {ms['load']:.0f} ms, "
        f"segmentation {ms['segment']:.0f} ms, mapping {mapping_ms:.0f} ms), without the dense cloud (`--cloud`: "
        f"{ms.get('cloud', 0.0):.0f} ms more).",
        f"- Storage: dense coloured point cloud {report['dense_point_cloud_bytes'] / 2**20:,.0f} MiB, `map.bt` "
        f"{sizes['map.bt'] / 1024:,.0f} KiB, `map.ot` {sizes['map.ot'] / 1024:,.0f} KiB, `map.semmap` "
        f"{sizes['map.semmap'] / 1024:,.0f} KiB.",
    ]


def end_to_end_section(bench: dict | None, heading: bool = True) -> list[str]:
    """The end-to-end table with its heading and how it was measured (nothing without results)."""
    if not bench:
        return []
    head = ["## End to end (`semmap run --online`)", ""] if heading else []
    return [*head, "`benchmarks/bench_end_to_end.py`: `semmap run` with `--poses slam` and ESPNetv2 s=2.0 (ONNX) "
            f"every {bench['segment_every']}th frame, online and offline (track first, then map) on the same frames, "
            "each in its own process; frames/s over a frame's work (start-up and writing files apart), latency from "
            "a frame's arrival to its voxels being in the map. `online` reads frames as fast as the loop takes them, "
            "so its latency is mostly the queue of frames waiting; `online@N Hz` replays them as a camera delivers "
            "them (`--rate N`, N the frame-rate target) and its latency is a frame's own:", "",
            *end_to_end_table(bench), ""]


def demo_headline_rows(demo: dict | None) -> list[tuple[str, str, str, str]]:
    """The demo's headline rows: the map against its network at the same pixels (one unit in the row), then the 3D
    map against the ground-truth voxels with its geometry and storage beside it, on a row of its own."""
    if not demo:
        return []
    seg, sizes = demo.get("segmenter", "oracle"), demo["bytes_on_disk"]
    return [(f"`make demo` ({demo['frames_used']} frames, realism `{demo.get('realism', 'clean')}`): "
             f"{headline.SAME_PIXELS}",
             f"map MIoU **{demo['pixel_miou_map']:.3f}**; {demo_ms(demo):.0f} ms per frame in all",
             f"shipped {seg} {demo['pixel_miou_network']:.3f} ({100 * demo['pixel_gain']:+.1f} points), "
             f"{100 * demo['pixel_coverage']:.0f} % of labelled pixels", "update_docs.py"),
            (f"`make demo`: {headline.VOXELS_3D}", f"mIoU {demo['miou_3d']:.3f}; `map.bt` "
             f"{sizes['map.bt'] / 1024:,.0f} KiB, `map.semmap` {sizes['map.semmap'] / 1024:,.0f} KiB",
             f"geometric precision {demo['geometric_precision_3d']:.3f}, coverage {demo['gt_coverage_3d']:.3f}; "
             f"dense cloud {demo['dense_point_cloud_bytes'] / 2**20:,.0f} MiB", "update_docs.py")]


def headline_rows(results: dict) -> list[str]:
    """The README's one table: a row per claim (what, semmap's number, the peer or truth in the same run, the
    script), from the same results as docs/BENCHMARKS.md; rows whose part has no results are left out."""
    rows: list[tuple[str, str, str, str]] = []
    octree = results.get("octree_vs_octomap")
    for r in (octree or {}).get("results", []):
        rows.append((f"Semantic OctoMap insertion, 640×480 frames, {r['resolution']} m",
                     f"{r['semmap_ms']} ms/frame (occupancy, colour, top-3)",
                     f"OctoMap {r['octomap_ms']} ms (occupancy only): **{r['speedup']}×**; cells in the same state "
                     f"{r['agreement']:.4%}", "bench_octree_vs_octomap.py"))
    if octree and octree.get("results"):
        r = octree["results"][0]
        rows.append((f"Memory per leaf, {r['resolution']} m", f"{r['semmap_bytes_per_leaf']} B",
                     f"OctoMap {r['octomap_bytes_per_leaf']} B", "bench_octree_vs_octomap.py"))
    rows += demo_headline_rows(results.get("demo"))
    tracking = results.get("tracking")
    if tracking:
        by = {(r["sequence"], r["method"]): r for r in tracking["results"]}
        seq = next((r["sequence"] for r in tracking["results"] if r["sequence"].startswith("7scenes")), None)
        if (seq, "semmap-slam") in by and (seq, tracking["peer"]) in by:
            a, b = by[seq, "semmap-slam"], by[seq, tracking["peer"]]
            rows.append((f"Camera tracking, {seq} ({a['frames']} frames)",
                         f"`slam` ATE {100 * a['ate_rmse_m']:.2f} cm, {a['ms_per_frame']:.0f} ms/frame",
                         f"Open3D odometry ({b['method']}) {100 * b['ate_rmse_m']:.2f} cm, "
                         f"{b['ms_per_frame']:.0f} ms/frame", "bench_tracking.py"))
    e2e = results.get("end_to_end")
    live = [r for r in (e2e or {}).get("results", []) if r.get("rate_hz") and r["sequence"].startswith("7scenes")]
    if live:
        r = live[0]
        rows.append((f"Online mapping, {r['sequence']}, SLAM poses, ESPNetv2 every {e2e['segment_every']}th frame, "
                     f"{r['resolution']} m", f"{r['fps']} frames/s at {r['rate_hz']:g} Hz input; latency "
                     f"{r['latency_ms']['median']:.0f} ms median, {r['latency_ms']['p95']:.0f} ms p95",
                     f"a {r['rate_hz']:g} Hz camera", "bench_end_to_end.py"))
    fusion = results.get("fusion")
    if fusion:
        def mean_of(key: str, kind: str, rule: str) -> float:
            return _mean(r[key] for r in fusion["results"] if (r["preset"], r["map"], r["fusion"], r["crf"]) ==
                         ("cnn-like", kind, rule, False))
        rows.append((f"Label fusion, simulated CNN output, {fusion['classes']} classes",
                     f"top-3 OctoMap mIoU {mean_of('miou', 'octomap', 'topk'):.3f} at "
                     f"{mean_of('bytes_per_voxel', 'octomap', 'topk'):.0f} B/voxel",
                     f"full Bayes voxel grid {mean_of('miou', 'voxelgrid', 'bayes'):.3f} at "
                     f"{mean_of('bytes_per_voxel', 'voxelgrid', 'bayes'):.0f} B/voxel", "bench_fusion.py"))
    loc = results.get("localization")
    if loc:
        sym = {g["model"]: g for g in loc["summary"] if g["rooms"] == "symmetric" and g["particles"] == 2000
               and g["init"] == "global"}
        if "semantic" in sym and "geometry" in sym:
            s, g = sym["semantic"], sym["geometry"]
            rows.append(("Global localization in rooms symmetric under a 180° turn",
                         f"semantic model converged in {round(s['converged_rate'] * s['runs'])} of {s['runs']} "
                         f"run{'s' if s['runs'] > 1 else ''}",
                         f"geometry alone {round(g['converged_rate'] * g['runs'])} of {g['runs']}",
                         "bench_localization.py"))
    sim = results.get("sim")
    if sim:
        rows.append((f"Simulator, {sim['width']}×{sim['height']}, `{sim.get('realism', 'clean')}`",
                     f"{sim['fps']} frames/s",
                     f"`clean` {sim.get('fps_clean', '?')}, ray casting {sim.get('fps_raycast', '?')}", "bench_sim.py"))
    return ["| measured | semmap | against | script |", "|---|---|---|---|",
            *(f"| {a} | {b} | {c} | `{d}` |" for a, b, c, d in rows[:HEADLINE_ROWS])]


#: Issue 46's targets for one shifted scene: network gain, map gain (points), forgetting (points), CPU minutes.
ADAPT_TARGETS = (5.0, 2.0, 1.0, 30.0)


def adapt_section(bench: dict | None) -> list[str]:
    """The BENCHMARKS.md section on ``semmap adapt`` under a sensor shift (nothing without bench_adapt.py's results)."""
    if not bench:
        return []
    gain, map_gain, forget, cpu = ADAPT_TARGETS
    rows = ["| scene | shift | network | network MIoU before -> after | map MIoU before -> after | forgetting | "
            "CPU min | pseudo-labels / network MIoU on the kept pixels |", "|---|---|---|---|---|---|---|---|"]
    met = 0
    for r in bench["results"]:
        rows.append(f"| {r['scene']} | {r['shift']} | {r['network']} | {r['miou_before']:.3f} -> {r['miou_after']:.3f} "
                    f"({100 * (r['miou_after'] - r['miou_before']):+.1f}) | {r['map_before']:.3f} -> "
                    f"{r['map_after']:.3f} ({100 * (r['map_after'] - r['map_before']):+.1f}) | {r['forgetting']:+.2f} "
                    f"| {r['cpu_min']:.1f} | {r.get('pseudo_miou') or 0:.3f} / "
                    f"{r.get('pseudo_network_miou') or 0:.3f} |")
        met += (100 * (r["miou_after"] - r["miou_before"]) >= gain and 100 * (r["map_after"] - r["map_before"])
                >= map_gain and r["forgetting"] <= forget and r["cpu_min"] <= cpu)
    return ["## The map teaches the network (`semmap adapt`)", "",
            f"`benchmarks/bench_adapt.py`: networks trained on `clean` scenes, on {bench['frames']}-frame hand-held "
            f"loops of scenes they never saw, rendered `kinect` or `hard` at {bench['image']}; mapped and adapted on "
            f"frames 0-{bench['split'] - 1}, scored at the pixels of every {bench['every']}th frame from "
            f"{bench['scored_from']} on (never seen in adaptation): the network before and after on the same pixels, "
            "the first map and the map re-made with the adapted network where both have a class. Forgetting: the "
            f"network's MIoU on the {bench['forget_frames']} `clean` test frames of `bench_networks.py` before minus "
            f"after, in points. CPU minutes: process time of one adaptation, {bench['threads']} torch thread(s).", "",
            *rows, "",
            f"Scenes meeting all four targets (network +{gain:g}, map +{map_gain:g}, forgetting <= {forget:g} point, "
            f"<= {cpu:g} CPU minutes): {met} of {len(bench['results'])}.", ""]


def kept_section() -> list[str]:
    """The hand-carried section of the current docs/BENCHMARKS.md, markers included (empty if it has none)."""
    try:
        text = (ROOT / "docs" / "BENCHMARKS.md").read_text()
    except OSError:
        return []
    if KEPT_START not in text or KEPT_END not in text:
        return []
    return [KEPT_START, *text.split(KEPT_START, 1)[1].split(KEPT_END, 1)[0].strip("\n").splitlines(), KEPT_END, ""]


def previous_stamp() -> tuple[str, str] | None:
    """(date, machine) of the current docs/BENCHMARKS.md's header line, or None."""
    try:
        line = (ROOT / "docs" / "BENCHMARKS.md").read_text().splitlines()[2]
    except (OSError, IndexError):
        return None
    if " on " not in line or "; machine: " not in line:
        return None
    date, where = line.split(" on ", 1)[1].split("; machine: ", 1)
    return date, where.rstrip(".")


#: part -> (key in the JSON block, script); the demo is run through the CLI.
PARTS = {"octree": ("octree_vs_octomap", "benchmarks/bench_octree_vs_octomap.py"),
         "sim": ("sim", "benchmarks/bench_sim.py"), "tracking": ("tracking", "benchmarks/bench_tracking.py"),
         "segmenters": ("segmenters", "benchmarks/bench_segmenters.py"),
         "fusion": ("fusion", "benchmarks/bench_fusion.py"), "demo": ("demo", None),
         "end_to_end": ("end_to_end", "benchmarks/bench_end_to_end.py"),
         "localization": ("localization", "benchmarks/bench_localization.py"),
         "networks": ("networks", "benchmarks/bench_networks.py"),
         "products": ("products", "benchmarks/bench_products.py"),
         "real": ("real", "benchmarks/bench_real.py"),
         "adapt": ("adapt", "benchmarks/bench_adapt.py")}
#: parts the docs can do without when an earlier run did not have them yet
OPTIONAL = {"end_to_end", "localization", "networks", "products", "real", "adapt"}
#: What the docs use of the demo's report (kept in the JSON block so ``--only`` can reuse it).
DEMO_KEYS = ("segmenter", "realism", "frames_segmented", "pixel_miou_map", "pixel_miou_network", "pixel_gain",
             "pixel_coverage", "pixel_every", "miou_3d", "geometric_precision_3d", "gt_coverage_3d", "frames_used",
             "ms_per_frame", "bytes_on_disk", "dense_point_cloud_bytes")


def previous_results() -> dict:
    """The JSON block of the current docs/BENCHMARKS.md (empty if there is none)."""
    try:
        text = (ROOT / "docs" / "BENCHMARKS.md").read_text()
        return json.loads(text.rsplit("```json", 1)[1].split("```", 1)[0])
    except (OSError, IndexError, ValueError):
        return {}


def collect(only: set[str] | None, quick: bool, given: dict) -> dict:
    """Every part's result: run if named in ``only`` (every part when None), else from ``given`` or the last docs
    (the demo may be missing: its lines are then kept as they are)."""
    extra = ["--quick"] if quick else []
    old = {**previous_results(), **given}
    out = {}
    for part, (key, script) in PARTS.items():
        if only is not None and part not in only:
            if key in old:
                out[key] = old[key]
            elif part not in OPTIONAL and part != "demo":
                raise SystemExit(f"update_docs: no earlier {part} results (docs/BENCHMARKS.md, --results); run it")
        elif script is None:
            report = run_demo(ROOT / "outputs" / "demo")
            seg = report.get("segmenter", "oracle")
            out[key] = {k: report[k] for k in (*DEMO_KEYS, f"{seg}_miou_2d") if k in report}
        else:
            out[key] = run_json([script, *extra])
    return out


def json_block(results: dict) -> str:
    """All results as one JSON object; bench_fusion's hundreds of result rows one per line."""
    parts = []
    for key, value in results.items():
        if key == "fusion":
            rows = ",\n  ".join(json.dumps(r) for r in value["results"])
            rest = json.dumps({k: v for k, v in value.items() if k != "results"})
            parts.append(f' "{key}": {{"results": [\n  {rows}],\n  {rest[1:]}')
        else:
            parts.append(f' "{key}": ' + json.dumps(value, indent=1).replace("\n", "\n "))
    return "{\n" + ",\n".join(parts) + "\n}"


def current_demo_lines() -> list[str]:
    """The demo lines of the current docs/BENCHMARKS.md (when the demo is neither run nor in the results)."""
    text = (ROOT / "docs" / "BENCHMARKS.md").read_text()
    section = text.split("## Demo (`semmap demo`)", 1)[1].split("```json", 1)[0]
    return [line for line in section.splitlines() if line.startswith("- ")]


def benchmarks_lines(results: dict, quick: bool, stamp: str, where: str) -> list[str]:
    """docs/BENCHMARKS.md: every part's tables and lines, the kept section and the JSON block of all results."""
    octree, sim, tracking = results["octree_vs_octomap"], results["sim"], results["tracking"]
    segmenters, fusion = results["segmenters"], results["fusion"]
    demo_text = demo_lines(results["demo"]) if "demo" in results else current_demo_lines()
    return [
        "# Benchmarks", "",
        f"Written by `benchmarks/update_docs.py{' --quick' if quick else ''}` on {stamp}; machine: {where}.",
        "Ratios compare semmap and its peer measured in the same run.", "",
        "## Semantic OctoMap insertion vs the OctoMap library", "",
        f"`benchmarks/bench_octree_vs_octomap.py`: {octree['frames']} frames from {octree['source']}, "
        f"{octree['points_per_frame']:,} points per frame; semmap inserts occupancy, colour and top-3 semantics, "
        "OctoMap (pyoctomap `OcTree.insertPointCloud`) occupancy only. Agreement: share of cells known to either map "
        "whose occupied / free / unknown state equals OctoMap's discretized insert.", "",
        *octree_table(octree), "",
        "Against the occupancy-only yardstick (`benchmarks/occupancy_reference.py`: a plain hash map, no colour or "
        "semantics), timed in turns with semmap, each frame's best of the repeats, median over frames; the sparse "
        "case takes every 50th 7-Scenes frame, so each brings much new space:", "",
        *octree_reference_table(octree), "",
        "Per-stage semmap times (ms/frame): " + "; ".join(
            f"{r['resolution']} m: " + ", ".join(f"{k} {v}" for k, v in r["semmap_stage_ms"].items())
            for r in octree["results"]), "",
        "## Simulator", "",
        f"`benchmarks/bench_sim.py`: {sim['fps']} frames/s at {sim['width']}×{sim['height']} with the "
        f"`{sim.get('realism', 'clean')}` preset's every channel (rgb through the colour camera, depth through the "
        f"sensor model, labels, instances; {sim.get('backend', 'raster')} backend); `clean` "
        f"{sim.get('fps_clean', '?')} frames/s in the same run; {sim.get('fps_raycast', '?')} frames/s with open3d "
        "ray casting.", "",
        "## Camera tracking", "",
        "`benchmarks/bench_tracking.py`: ATE (RMSE after SE(3) Umeyama alignment) and RPE (1 frame) with evo, on the "
        "real 7-Scenes frames (ground truth from KinectFusion) and simulated sequences (exact ground truth); "
        f"`{tracking['peer']}` is Open3D's legacy hybrid RGB-D odometry chained frame to frame. The Sim(3) scale "
        "maps a trajectory onto the ground truth with scale fitted too: away from 1, the depth calibration and the "
        "ground truth disagree (`scripts/research/seven_scenes_scale_check.py`).", "",
        *tracking_table(tracking, sim3=True), "",
        "## Segmentation speed", "",
        "`benchmarks/bench_segmenters.py`: ESPNetv2 on 640×480 7-Scenes frames, 2 CPU threads; a frame's time "
        "covers resizing, the network, softmax, sampling at every pixel and top-3.", "",
        *segmenter_table(segmenters), "",
        "## Label fusion and maps", "",
        f"`benchmarks/bench_fusion.py{' --quick' if fusion.get('quick') else ''}`: {len(fusion['upper_bound'])} "
        f"simulated scenes ({', '.join(fusion['upper_bound'])}), {fusion['frames']} frames each at 320×240, "
        f"{fusion['classes']} classes; every map fed the same frames in one pass, scored against the scenes' "
        f"ground-truth voxels at {fusion['resolution']} m (the point map, {fusion['point_resolution']} m, votes "
        "per voxel), then refined by the 3D CRF and scored again. Means over the scenes; B/voxel is memory per "
        "stored voxel or point; ms/frame is integration only, on a machine shared with other jobs.", "",
        *fusion_table(fusion), "", *fusion_targets(fusion), "",
        *end_to_end_section(results.get("end_to_end")),
        *localization_section(results.get("localization")),
        *networks_section(results.get("networks"), results.get("real")),
        *real_section(results.get("real")),
        *products_section(results.get("products")),
        *adapt_section(results.get("adapt")),
        *kept_section(),
        "## Demo (`semmap demo`)", "", *demo_text, "",
        "```json", json_block(results), "```", "",
    ]


def write_readme_headline(results: dict, stamp: str, where: str) -> None:
    """Replace README.md's headline block (between START and END) with the headline table; no markers, no change."""
    readme = (ROOT / "README.md").read_text()
    if START not in readme or END not in readme:
        return
    block = [START, "", *headline_rows(results), "",
             f"Measured on {stamp} ({where}) by `benchmarks/update_docs.py`; every number and how it was measured: "
             "[docs/BENCHMARKS.md](docs/BENCHMARKS.md).", END]
    head, rest = readme.split(START, 1)
    (ROOT / "README.md").write_text(head + "\n".join(block) + rest.split(END, 1)[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="quick variants of the benchmarks")
    ap.add_argument("--only", default="", help=f"comma-separated parts to re-run: {', '.join(PARTS)}, or none")
    ap.add_argument("--results", type=Path, help="JSON object of part results to use instead of running them")
    args = ap.parse_args()
    only = {p.strip() for p in args.only.split(",") if p.strip()} or None
    if only == {"none"}:
        only = set()
    unknown = (only or set()) - set(PARTS)
    if unknown:
        raise SystemExit(f"update_docs: unknown part(s) {', '.join(sorted(unknown))}; choose from {', '.join(PARTS)}")
    given = json.loads(args.results.read_text()) if args.results else {}
    results = collect(only, args.quick, given)
    previous = previous_stamp() if only == set() else None
    stamp, where = previous or (time.strftime("%Y-%m-%d"), machine())
    (ROOT / "docs" / "BENCHMARKS.md").write_text("\n".join(benchmarks_lines(results, args.quick, stamp, where)))
    write_readme_headline(results, stamp, where)
    octree, sim, fusion = results["octree_vs_octomap"], results["sim"], results["fusion"]
    demo_report = results.get("demo", {})
    print(json.dumps({"octree": octree["results"], "sim_fps": sim["fps"], "miou_3d": demo_report.get("miou_3d"),
                      "segmenter": demo_report.get("segmenter", "oracle"),
                      "miou_2d": demo_report.get(f"{demo_report.get('segmenter', 'oracle')}_miou_2d"),
                      "fusion_upper_bound": fusion["upper_bound"], "fusion_timing": fusion["timing"]}))


if __name__ == "__main__":
    main()
