"""Synthetic frames, trajectories and on-disk sequences for tests (small, deterministic)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from semmap.types import CameraIntrinsics, Frame, make_pose

SMALL_CAMERA = CameraIntrinsics(32, 24, 30.0, 30.0, 15.5, 11.5)


def run_cli(*args: object) -> subprocess.CompletedProcess:
    """``semmap ARGS`` run in this process as the ``semmap`` entry point runs it: the exit code, stdout and stderr
    a finished process would give, without the seconds a new interpreter spends importing semmap and loading its
    kernels. A bug's exception propagates, so the test fails with its traceback. Killing a run, Ctrl-C and the
    entry point itself need a real process: :func:`run_cli_process`."""
    import contextlib
    import io
    import logging

    from semmap.cli import main

    out, err = io.StringIO(), io.StringIO()
    root = logging.getLogger()
    handlers, level, argv = root.handlers[:], root.level, sys.argv
    code = 0
    sys.argv = ["semmap", *map(str, args)]
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main()
            except SystemExit as exc:
                if isinstance(exc.code, str):  # as the interpreter does: the text on stderr, exit code 1
                    print(exc.code, file=sys.stderr)
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:  # the command's logging set-up and arguments stay with it
        sys.argv = argv
        root.handlers[:] = handlers
        root.setLevel(level)
    return subprocess.CompletedProcess(["semmap", *map(str, args)], code, out.getvalue(), err.getvalue())


def run_cli_process(*args: object, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m semmap.cli ARGS`` in a new process (exit code, stdout, stderr)."""
    return subprocess.run([sys.executable, "-m", "semmap.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def rotation_z(angle: float) -> np.ndarray:
    """Rotation about the z axis by ``angle`` radians."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def make_frames(
    n: int,
    *,
    camera: CameraIntrinsics = SMALL_CAMERA,
    seed: int = 0,
    t0: float = 1305031102.175304,
    dt: float = 1 / 30,
    with_labels: bool = True,
) -> list[Frame]:
    """``n`` frames with random images, a few invalid depth pixels and a slowly turning, moving camera."""
    rng = np.random.default_rng(seed)
    h, w = camera.height, camera.width
    frames = []
    for i in range(n):
        depth = rng.uniform(0.3, 6.0, (h, w)).astype(np.float32)
        depth[rng.random((h, w)) < 0.1] = 0.0
        frames.append(Frame(
            index=i,
            timestamp=t0 + i * dt,
            rgb=rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
            depth=depth,
            intrinsics=camera,
            T_world_cam=make_pose(rotation_z(0.05 * i), [0.1 * i, -0.02 * i, 1.0]),
            labels=rng.integers(0, 300, (h, w)).astype(np.uint16) if with_labels else None,
            instances=rng.integers(0, 1000, (h, w)).astype(np.int32) if with_labels else None,
            name=f"{t0 + i * dt:.6f}",
        ))
    return frames


def write_png(path: Path, image: np.ndarray) -> Path:
    """Write ``image`` as PNG exactly as given (no colour conversion)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, data = cv2.imencode(".png", image)
    assert ok, path
    path.write_bytes(data.tobytes())
    return path


def write_7scenes_sequence(root: Path, frames: Iterable[Frame], *, color_ext: str = ".png",
                           write_intrinsics: bool = True) -> Path:
    """Write frames in 7-Scenes layout (``frame-NNNNNN.*``, frame number = ``frame.index``, depth in mm)."""
    root.mkdir(parents=True, exist_ok=True)
    camera = None
    for frame in frames:
        camera = frame.intrinsics
        stem = root / f"frame-{frame.index:06d}"
        bgr = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR)
        if color_ext == ".png":
            write_png(Path(f"{stem}.color.png"), bgr)
        else:
            cv2.imwrite(f"{stem}.color{color_ext}", bgr)
        write_png(Path(f"{stem}.depth.png"), np.rint(frame.depth * 1000).astype(np.uint16))
        if frame.T_world_cam is not None:
            np.savetxt(f"{stem}.pose.txt", frame.T_world_cam)
    if write_intrinsics and camera is not None:
        np.savetxt(root / "camera-intrinsics.txt", camera.K)
    return root


ROOM_CAMERA = CameraIntrinsics(80, 60, 70.0, 70.0, 39.5, 29.5)
ROOM_LO = np.array([-2.0, -1.5, 0.0])
ROOM_HI = np.array([2.0, 1.5, 2.5])


def make_room_frames(n: int, *, camera: CameraIntrinsics = ROOM_CAMERA, start: float = 0.0) -> list[Frame]:
    """Frames inside an empty box room, ray-cast analytically: depth, colour and labels (class = face 1..6)."""
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(u.shape)], -1)
    frames = []
    for i in range(n):
        a = start + 0.4 * i
        origin = np.array([0.3 * np.cos(a), 0.3 * np.sin(a), 1.3])
        fwd = np.array([np.cos(a + 0.8), np.sin(a + 0.8), -0.2])
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        R = np.stack([right, np.cross(fwd, right), fwd], 1)
        d = rays @ R.T  # world directions, unit depth along the optical axis
        with np.errstate(divide="ignore", invalid="ignore"):
            t_face = np.where(d > 0, (ROOM_HI - origin) / d, np.where(d < 0, (ROOM_LO - origin) / d, np.inf))
        axis = np.argmin(t_face, axis=-1)
        depth = np.take_along_axis(t_face, axis[..., None], -1)[..., 0].astype(np.float32)
        positive = np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0
        labels = (1 + 2 * axis + positive).astype(np.uint16)
        hit = origin + d * depth[..., None]
        stripes = ((np.floor(hit[..., 0] * 5) + np.floor(hit[..., 1] * 5) + np.floor(hit[..., 2] * 5)) % 2)
        rgb = (40 * labels[..., None] % 200 + 30 + 20 * stripes[..., None]).astype(np.uint8).repeat(3, -1)
        frames.append(Frame(index=i, timestamp=i / 30, rgb=np.ascontiguousarray(rgb), depth=depth,
                            intrinsics=camera, T_world_cam=make_pose(R, origin), labels=labels,
                            name=f"{i / 30:.6f}"))
    return frames


def room_label_set():
    from semmap.types import LabelSet

    names = ("unknown", "wall_x-", "wall_x+", "wall_y-", "wall_y+", "floor", "ceiling")
    colors = np.array([[0, 0, 0], [200, 60, 60], [60, 200, 60], [60, 60, 200], [200, 200, 60], [150, 120, 90],
                       [90, 90, 90]], np.uint8)
    return LabelSet(names, colors)


def umeyama_ate(est: np.ndarray, gt: np.ndarray) -> float:
    """ATE RMSE (m) after rigid alignment of estimated to true camera positions."""
    src, dst = est[:, :3, 3], gt[:, :3, 3]
    ms, md = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((dst - md).T @ (src - ms))
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ S @ Vt
    aligned = (src - ms) @ R.T + md
    return float(np.sqrt(((aligned - dst) ** 2).sum(1).mean()))


def blank_frame(frame: Frame, stamp: float) -> Frame:
    """``frame`` with black colour and no depth (a blinded sensor), at timestamp ``stamp``."""
    return frame.with_(rgb=np.zeros_like(frame.rgb), depth=np.zeros_like(frame.depth), timestamp=stamp,
                       name=f"blank{stamp:.3f}")
