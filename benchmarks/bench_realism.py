"""Depth realism: the simulator's depth (a ``--realism`` preset) against the real 7-Scenes Kinect frames.

Two statistics, measured the same way on both (the simulated frames are rendered with 7-Scenes' depth camera,
640x480, f = 585 px, in kitchen scenes):

- plane residual at 1, 2 and 3 m: the image is cut into 20x20-pixel patches; a patch with >= 90 % valid depth whose
  median depth lies in a bin (1 +- 0.15, 2 +- 0.2, 3 +- 0.3 m) is back-projected, a plane is fitted by RANSAC
  (64 hypotheses, inlier band 2 mm + 4 mm/m^2 z^2), patches with >= 80 % inliers count, and the plane is refitted
  to the inliers by least squares; the bin's residual is the median over patches of the RMS point-to-plane distance;
- hole fraction near depth edges: a pixel is near an edge when the valid depths within 15x15 pixels around it
  differ by more than 10 % of the nearest; the fraction of such pixels that have no depth.

Prints a table and one JSON line last: {"bench": "realism", "realism": ..., "plane_residual_mm": {...},
"edge_hole_fraction": {...}, "within_30pct": ...}. ``--figure PNG`` writes a real and a simulated depth image
side by side (and the same view with ``clean``).

    python benchmarks/bench_realism.py [--quick] [--realism kinect] [--frames N] [--figure docs/images/x.png]
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets.sevenscenes import SEVEN_SCENES_DEPTH_CAMERA, SevenScenesDataset
from semmap.files.atomic import write_bytes_atomic
from semmap.sim.realism import REALISMS, realism
from semmap.sim.render import Renderer
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import CameraIntrinsics

SEVEN_SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "7scenes-redkitchen"
#: Depth bins: centre (m) -> half width (m).
BINS = {1.0: 0.15, 2.0: 0.2, 3.0: 0.3}
PATCH = 20
EDGE_WINDOW = 15
EDGE_JUMP_REL = 0.10
#: Simulated views: (scene seed, trajectory kind) of kitchen scenes.
SIM_VIEWS = ((0, "walk"), (1, "loop"), (2, "walk"), (3, "loop"))
TOLERANCE = 0.30


def patch_residuals(depth: np.ndarray, cam: CameraIntrinsics, rng: np.random.Generator) -> dict[float, list[float]]:
    """RMS plane residual (metres) of every planar patch of ``depth``, by depth bin."""
    H, W = depth.shape
    h, w = H // PATCH, W // PATCH
    z = depth[: h * PATCH, : w * PATCH].reshape(h, PATCH, w, PATCH).transpose(0, 2, 1, 3).reshape(h * w, -1)
    v, u = np.mgrid[: h * PATCH, : w * PATCH].astype(np.float64)
    u = u.reshape(h, PATCH, w, PATCH).transpose(0, 2, 1, 3).reshape(h * w, -1)
    v = v.reshape(h, PATCH, w, PATCH).transpose(0, 2, 1, 3).reshape(h * w, -1)
    out: dict[float, list[float]] = {c: [] for c in BINS}
    for i in range(h * w):
        ok = z[i] > 0
        if ok.mean() < 0.9:
            continue
        zi = z[i][ok].astype(np.float64)
        med = float(np.median(zi))
        centre = next((c for c, half in BINS.items() if abs(med - c) <= half), None)
        if centre is None:
            continue
        pts = np.stack([(u[i][ok] - cam.cx) / cam.fx * zi, (v[i][ok] - cam.cy) / cam.fy * zi, zi], 1)
        res = _ransac_rms(pts, 0.002 + 0.004 * med**2, rng)
        if res is not None:
            out[centre].append(res)
    return out


def _ransac_rms(pts: np.ndarray, band: float, rng: np.random.Generator, hypotheses: int = 64) -> float | None:
    """RMS distance of the inliers to the least-squares plane of the best RANSAC plane (None: not planar)."""
    idx = rng.integers(0, len(pts), (hypotheses, 3))
    a, b, c = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    good = norm > 1e-12
    if not good.any():
        return None
    n, a = n[good] / norm[good, None], a[good]
    dist = np.abs((pts[None] - a[:, None]) @ n[..., None])[..., 0]  # (K, N)
    inl = dist < band
    best = int(inl.sum(1).argmax())
    mask = inl[best]
    if mask.mean() < 0.8:
        return None
    q = pts[mask]
    q = q - q.mean(0)
    normal = np.linalg.svd(q, full_matrices=False)[2][-1]
    return float(np.sqrt(np.mean((q @ normal) ** 2)))


def edge_holes(depth: np.ndarray) -> tuple[int, int]:
    """(pixels near a depth edge, of them without depth)."""
    valid = depth > 0
    kernel = np.ones((EDGE_WINDOW, EDGE_WINDOW), np.uint8)
    zmax = cv2.dilate(np.where(valid, depth, 0).astype(np.float32), kernel)
    zmin = cv2.erode(np.where(valid, depth, np.inf).astype(np.float32), kernel)
    near = np.isfinite(zmin) & (zmax - zmin > EDGE_JUMP_REL * zmin)
    return int(near.sum()), int((near & ~valid).sum())


def real_frames(n: int) -> list[np.ndarray]:
    """``n`` depth images spread over the 7-Scenes sequence (empty when it is absent)."""
    if not SEVEN_SCENES.is_dir():
        print(f"7-Scenes frames not found at {SEVEN_SCENES}; nothing to compare with", file=sys.stderr)
        return []
    ds = SevenScenesDataset(SEVEN_SCENES, register_color=False)
    step = max(1, len(ds) // n)
    return [f.depth for i, f in enumerate(ds) if i % step == 0][:n]


def sim_frames(preset: str, n: int, first_only: bool = False) -> list[np.ndarray]:
    """``n`` depth images of kitchen scenes rendered with ``preset`` through 7-Scenes' depth camera (only the
    first of them with ``first_only``)."""
    per = -(-n // len(SIM_VIEWS))
    out: list[np.ndarray] = []
    for seed, kind in SIM_VIEWS[:1] if first_only else SIM_VIEWS:
        scene = generate_scene(seed, "kitchen", "medium")
        poses = make_trajectory(scene, kind, per, seed=seed, fps=per / 20.0)  # spread over 20 s of the path
        r = Renderer(scene, SEVEN_SCENES_DEPTH_CAMERA, noise=realism(preset).depth_model(seed) or False)
        out += [r.render(T, frame_index=i).depth for i, T in enumerate(poses[:1] if first_only else poses)]
    return out[:n]


def statistics(frames: list[np.ndarray]) -> dict:
    """Median plane residual (mm) per bin with its patch count, and the hole fraction near edges."""
    rng = np.random.default_rng(0)
    per_bin: dict[float, list[float]] = {c: [] for c in BINS}
    near = holes = 0
    for d in frames:
        for c, r in patch_residuals(d, SEVEN_SCENES_DEPTH_CAMERA, rng).items():
            per_bin[c] += r
        a, b = edge_holes(d)
        near, holes = near + a, holes + b
    valid = float(np.mean([np.mean(d > 0) for d in frames])) if frames else float("nan")
    return {"plane_residual_mm": {f"{c:g}m": round(1e3 * float(np.median(r)), 2) if r else None
                                  for c, r in per_bin.items()},
            "patches": {f"{c:g}m": len(r) for c, r in per_bin.items()},
            "edge_hole_fraction": round(holes / max(near, 1), 4), "valid_fraction": round(valid, 4)}


def figure(path: Path, real: np.ndarray, sim: np.ndarray, clean: np.ndarray, preset: str) -> None:
    """Real, simulated (``preset``) and clean depth side by side, one colour scale, no depth in black."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    cmap = matplotlib.colormaps["turbo"].copy()
    cmap.set_bad("black")
    for ax, d, title in zip(axes, (real, sim, clean),
                            ("7-Scenes redkitchen (Kinect v1)", f"simulated kitchen, --realism {preset}",
                             "the same view, --realism clean"), strict=True):
        im = ax.imshow(np.where(d > 0, d, np.nan), cmap=cmap, vmin=0.5, vmax=4.0)
        ax.set_title(title)
        ax.axis("off")
    fig.colorbar(im, ax=axes, shrink=0.8, label="depth (m); black: no depth")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())


def compare(real: dict, sim: dict) -> dict:
    """Ratios simulated / real and whether each lies within the tolerance."""
    ratios = {k: (None if real["plane_residual_mm"][k] is None or sim["plane_residual_mm"][k] is None
                  else round(sim["plane_residual_mm"][k] / real["plane_residual_mm"][k], 3))
              for k in real["plane_residual_mm"]}
    ratios["edge_holes"] = round(sim["edge_hole_fraction"] / max(real["edge_hole_fraction"], 1e-9), 3)
    ok = all(r is not None and abs(r - 1.0) <= TOLERANCE for r in ratios.values())
    return {"ratio": ratios, "within_30pct": ok}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="12 frames of each (for CI)")
    parser.add_argument("--realism", default="kinect", choices=REALISMS, help="the simulator's preset")
    parser.add_argument("--frames", type=int, default=40, help="frames of each side")
    parser.add_argument("--figure", type=Path, default=None, help="write the side-by-side depth figure here")
    args = parser.parse_args()
    n = 12 if args.quick else args.frames
    real_d = real_frames(n)
    sim_d = sim_frames(args.realism, n)
    real = statistics(real_d) if real_d else None
    sim = statistics(sim_d)
    print(f"{'':24}{'7-Scenes':>12}{'sim ' + args.realism:>14}")
    for k in sim["plane_residual_mm"]:
        print(f"plane residual {k:>4} mm {real and real['plane_residual_mm'][k]!s:>12}"
              f"{sim['plane_residual_mm'][k]!s:>14}   patches {real and real['patches'][k]} / {sim['patches'][k]}")
    print(f"hole fraction near edges {real and real['edge_hole_fraction']!s:>11}{sim['edge_hole_fraction']:>14}")
    print(f"valid depth fraction     {real and real['valid_fraction']!s:>11}{sim['valid_fraction']:>14}")
    row = {"bench": "realism", "realism": args.realism, "frames": n, "real": real, "sim": sim,
           **(compare(real, sim) if real else {})}
    if args.figure is not None and real_d:
        clean = sim_frames("clean", n, first_only=True)[0]
        figure(args.figure, real_d[len(real_d) // 3], sim_d[0], clean, args.realism)
    print(json.dumps(row))


if __name__ == "__main__":
    main()
