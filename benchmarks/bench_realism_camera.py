"""Colour camera and hand motion of the simulator against 7-Scenes: image sharpness and speed distributions.

Image statistics (on grey levels 0-255, per frame, median over the frames): mean Sobel gradient magnitude,
variance of the Laplacian (sharpness; falls with blur), noise sigma (Immerkaer's estimator: falls with blur,
rises with sensor noise), mean brightness and its spread over the sequence (exposure drift). Real frames are
7-Scenes redkitchen's colour files as recorded (jpg, not registered onto depth); simulated frames are rendered
along hand-held ``kinect`` trajectories with the ``kinect`` colour camera (and, for reference, the clean camera on
the same poses and on the smooth clean trajectory). Motion: per-frame linear and angular speed quantiles
(5/25/50/75/95 %) and high-pass jitter of 7-Scenes' ground truth against simulated ``kinect`` and ``clean``
trajectories of every kind. Render speed: frames/s of the renderer (depth noise on) with the clean and the
``kinect`` colour camera on the same poses, measured in this run.

Writes the side-by-side picture (real | simulated kinect | simulated clean) with ``--figure``. Prints a table and
one JSON line last: {"bench": "realism-camera", "realism": "kinect", ...}.

    python benchmarks/bench_realism_camera.py [--quick] [--figure docs/images/realism_camera.png]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets.sevenscenes import read_pose
from semmap.sim.camera_model import colour_params
from semmap.sim.hand_motion import jitter_stats, motion_params, speed_stats
from semmap.sim.noise import KinectNoise
from semmap.sim.render import Renderer
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import TRAJECTORY_KINDS, make_trajectory
from semmap.viz.preview import side_by_side, write_png

SEVEN_SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "7scenes-redkitchen"
#: Simulated scenes (seed, kind) the statistics are taken over.
SCENES = ((3, "kitchen"), (0, "office"))
_IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def image_stats(rgb: np.ndarray) -> dict[str, float]:
    """Gradient, sharpness, noise and brightness of one colour image."""
    g = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    lap = cv2.Laplacian(g, cv2.CV_32F)
    conv = cv2.filter2D(g, cv2.CV_32F, _IMMERKAER)[1:-1, 1:-1]
    noise = math.sqrt(math.pi / 2) * float(np.abs(conv).mean()) / 6.0
    return {"gradient": float(np.hypot(gx, gy).mean()), "laplacian_var": float(lap.var()), "noise_sigma": noise,
            "brightness": float(g.mean())}


def summary(frames: list[np.ndarray]) -> dict[str, float]:
    """Median of each image statistic over ``frames`` and the spread of their brightness."""
    rows = [image_stats(f) for f in frames]
    out = {k: round(float(np.median([r[k] for r in rows])), 3) for k in rows[0]}
    out["brightness_std"] = round(float(np.std([r["brightness"] for r in rows])), 3)
    out["frames"] = len(rows)
    return out


def real_frames(n: int) -> tuple[list[np.ndarray], np.ndarray]:
    """``n`` colour images spread over the 7-Scenes sequence, and all its ground-truth poses."""
    colours = sorted(SEVEN_SCENES.glob("frame-*.color.*"))
    poses = np.stack([read_pose(p) for p in sorted(SEVEN_SCENES.glob("frame-*.pose.txt"))])
    pick = np.linspace(0, len(colours) - 1, n).round().astype(int)
    return [cv2.cvtColor(cv2.imread(str(colours[i]), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB) for i in pick], poses


def sim_frames(n: int, frames: int) -> dict[str, list[np.ndarray]]:
    """Frames of the simulated scenes: kinect camera on kinect motion, clean camera on the same poses, and clean
    camera on the clean (smooth) trajectory."""
    out: dict[str, list[np.ndarray]] = {"kinect": [], "clean_camera": [], "clean": []}
    for seed, kind in SCENES:
        scene = generate_scene(seed, kind, "medium")
        hand = make_trajectory(scene, "loop", frames, seed=seed, motion=motion_params("kinect"))
        smooth = make_trajectory(scene, "loop", frames, seed=seed)
        real_cam = Renderer(scene, colour=colour_params("kinect", seed))
        ideal = Renderer(scene)
        for i in np.linspace(1, frames - 2, max(1, n // len(SCENES))).round().astype(int):
            out["kinect"].append(real_cam.render_in(hand, int(i)).rgb)
            out["clean_camera"].append(ideal.render_in(hand, int(i)).rgb)
            out["clean"].append(ideal.render_in(smooth, int(i)).rgb)
    return out


def motion_stats(frames: int) -> dict[str, dict]:
    """Speed quantiles and jitter of simulated trajectories of every kind, kinect and clean."""
    out = {}
    for preset in ("kinect", "clean"):
        poses = []
        for seed, kind in SCENES:
            scene = generate_scene(seed, kind, "medium")
            poses += [make_trajectory(scene, k, frames, seed=seed, motion=motion_params(preset))
                      for k in TRAJECTORY_KINDS]
        stats = _pooled_speeds(poses)
        stats.update(jitter_stats(poses[0]))
        out[preset] = stats
    return out


def _pooled_speeds(trajectories: list[np.ndarray]) -> dict:
    """Speed quantiles over every frame of several trajectories (not across their joins)."""
    from semmap.sim.hand_motion import QUANTILES, frame_speeds

    v = np.concatenate([frame_speeds(p)[0] for p in trajectories])
    w = np.concatenate([frame_speeds(p)[1] for p in trajectories])
    return {"speed_q": [round(float(x), 4) for x in np.percentile(v, QUANTILES)],
            "angular_q_deg": [round(float(x), 3) for x in np.degrees(np.percentile(w, QUANTILES))]}


def render_speed(frames: int) -> dict[str, float]:
    """Frames/s at 640x480 (depth noise on) with the clean and the kinect colour camera, interleaved."""
    scene = generate_scene(0, "office", "medium")
    poses = make_trajectory(scene, "loop", frames, seed=0, motion=motion_params("kinect"))
    renderers = {"clean": Renderer(scene, noise=KinectNoise(seed=0)),
                 "kinect": Renderer(scene, noise=KinectNoise(seed=0), colour=colour_params("kinect"))}
    spent = dict.fromkeys(renderers, 0.0)
    for r in renderers.values():
        r.render_in(poses, 0)
    for i in range(len(poses)):
        for name, r in renderers.items():
            t0 = time.perf_counter()
            r.render_in(poses, i)
            spent[name] += time.perf_counter() - t0
    return {f"fps_{k}": round(len(poses) / s, 2) for k, s in spent.items()}


def _centre(rgb: np.ndarray, h: int = 240, w: int = 320) -> np.ndarray:
    """The middle ``w`` x ``h`` pixels at full resolution (sharpness shows 1:1; the PNG stays small)."""
    y, x = (rgb.shape[0] - h) // 2, (rgb.shape[1] - w) // 2
    return rgb[y:y + h, x:x + w]


def _ratio(sim: dict, real: dict) -> dict:
    return {k: round(sim[k] / real[k], 3) for k in ("gradient", "laplacian_var", "noise_sigma") if real[k]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer frames")
    parser.add_argument("--figure", type=Path, help="PNG to write: real | simulated kinect | simulated clean")
    args = parser.parse_args()
    n_images, n_frames = (8, 150) if args.quick else (40, 600)
    result: dict = {"bench": "realism-camera", "realism": "kinect"}
    sim = sim_frames(n_images, n_frames)
    result["images"] = {name: summary(f) for name, f in sim.items()}
    result["motion"] = motion_stats(n_frames)
    if SEVEN_SCENES.is_dir():
        real, poses = real_frames(n_images)
        result["images"]["7scenes"] = summary(real)
        result["motion"]["7scenes"] = {**speed_stats(poses), **jitter_stats(poses)}
        result["ratio_kinect_to_7scenes"] = _ratio(result["images"]["kinect"], result["images"]["7scenes"])
        result["ratio_clean_to_7scenes"] = _ratio(result["images"]["clean"], result["images"]["7scenes"])
        if args.figure:
            crops = [_centre(im) for im in (real[len(real) // 2], sim["kinect"][1], sim["clean"][1])]
            write_png(args.figure, side_by_side(crops, ["7-Scenes redkitchen (real)", "simulated, kinect",
                                                        "simulated, clean"]))
    else:
        print(f"note: {SEVEN_SCENES} is absent: simulated statistics only")
    result.update(render_speed(30 if args.quick else 90))
    _print_table(result)
    print(json.dumps(result))


def _print_table(result: dict) -> None:
    images, motion = result["images"], result["motion"]
    print(f"{'images':14s} {'gradient':>9s} {'lap.var':>9s} {'noise':>7s} {'bright':>7s} {'b.std':>6s}")
    for name, s in images.items():
        print(f"{name:14s} {s['gradient']:9.2f} {s['laplacian_var']:9.1f} {s['noise_sigma']:7.2f} "
              f"{s['brightness']:7.1f} {s['brightness_std']:6.1f}")
    print(f"{'motion':10s} {'speed m/s 5/25/50/75/95 %':36s} {'angular deg/s':32s} jitter mm / deg")
    for name, s in motion.items():
        print(f"{name:10s} {' '.join(f'{x:6.3f}' for x in s['speed_q']):36s} "
              f"{' '.join(f'{x:5.1f}' for x in s['angular_q_deg']):32s} {s['jitter_mm']} {s['jitter_deg']}")
    print(f"render: {result['fps_clean']} frames/s clean camera, {result['fps_kinect']} frames/s kinect camera")


if __name__ == "__main__":
    main()
