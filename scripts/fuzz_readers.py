"""Fuzz every semmap reader with atheris (coverage-guided): each input is written to a file of the reader's kind and
read back; anything but a result or a ``semmap.errors.SemmapError`` (a traceback from inside numpy, numba, zipfile,
rosbags, ...) is a crash that atheris reports with the input that caused it.

    pip install -e '.[dev]'                  # atheris is a dev extra
    .venv/bin/python scripts/fuzz_readers.py --list
    .venv/bin/python scripts/fuzz_readers.py octomap --runs 20000 [--corpus DIR]
    .venv/bin/python scripts/fuzz_readers.py all --runs 2000           # every reader in turn, one process each

Seeds are valid files written by semmap itself (a small map, trajectory, sequence index, bag), so mutations start
from the real formats. Prints one JSON line per reader: inputs run, seconds, and whether it crashed. The same
targets run under hypothesis, with a bounded number of examples, in ``tests/test_fuzz_readers.py``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

# --------------------------------------------------------------------------------------------------
# Seeds: small valid files of every format
# --------------------------------------------------------------------------------------------------


def _small_map():
    from semmap.maps.semantic_octomap import SemanticOctoMap
    from semmap.types import LabelSet, TopKProbs

    rng = np.random.default_rng(0)
    labels = LabelSet(("unknown", "wall", "floor"), np.array([[0, 0, 0], [200, 0, 0], [0, 200, 0]], np.uint8))
    m = SemanticOctoMap(0.2, label_set=labels)
    points = rng.uniform(-0.6, 0.6, (60, 3)).astype(np.float32)
    probs = np.tile(np.array([[0.7, 0.2, 0.1]], np.float32), (60, 1))
    ids = np.tile(np.array([[1, 2, 0]], np.uint16), (60, 1))
    m.insert_points(points, np.array([0.0, 0.0, 2.0]), colors=rng.integers(0, 255, (60, 3), dtype=np.uint8),
                    semantics=TopKProbs(ids, probs))
    return m


def seed_files(folder: Path) -> dict[str, bytes]:
    """Valid example bytes per target name, written by semmap's own writers."""
    from semmap.io.native import save_map
    from semmap.io.octomap_files import write_bt, write_ot
    from semmap.io.ply import write_ply
    from semmap.io.trajectory import write_trajectory
    from semmap.types import Trajectory, make_pose

    folder.mkdir(parents=True, exist_ok=True)
    m = _small_map()
    tree = m.tree()
    seeds = {
        "octomap": (write_ot(folder / "s.ot", tree, m.resolution, color=True), folder / "s.ot"),
        "octomap_bt": (write_bt(folder / "s.bt", tree, m.resolution), folder / "s.bt"),
        "semmap": (save_map(folder / "s.semmap", m), folder / "s.semmap"),
        "ply": (write_ply(folder / "s.ply", m.cloud()), folder / "s.ply"),
    }
    traj = Trajectory(np.arange(4) / 30.0, np.stack([make_pose(np.eye(3), [i, 0, 0]) for i in range(4)]))
    write_trajectory(folder / "s.txt", traj)
    out = {name: path.read_bytes() for name, (_, path) in seeds.items()}
    out["trajectory"] = (folder / "s.txt").read_bytes()
    out["tum_index"] = _tum_index_seed()
    out["labelset"] = json.dumps(m.label_set.to_dict()).encode()
    out["sevenscenes_pose"] = " ".join(f"{v:.6f}" for v in np.eye(4).ravel()).encode()
    out["rosbag"] = _bag_seed(folder / "s.bag")
    out["scannet_sens"] = _sens_seed(folder / "scan")
    out["replica_traj"] = "\n".join(" ".join(f"{v:g}" for v in make_pose(np.eye(3), [i, 0, 0]).ravel())
                                    for i in range(3)).encode()
    return out


def _sens_seed(folder: Path) -> bytes:
    """A ScanNet .sens stream of two 8x6 frames, written by semmap's layout writer."""
    from semmap.io.benchmark_layouts import write_scannet_scan
    from semmap.labels import INDOOR_LABELS, NYU40_NAMES, simulator_to_nyu40
    from semmap.types import CameraIntrinsics, Frame, make_pose

    cam = CameraIntrinsics(8, 6, 5.0, 5.0, 3.5, 2.5)
    frames = [Frame(i, i / 30, np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32), cam,
                    make_pose(np.eye(3), [i, 0, 0])) for i in range(2)]
    write_scannet_scan(folder, frames, INDOOR_LABELS, simulator_to_nyu40(), NYU40_NAMES, scan="s")
    return (folder / "s.sens").read_bytes()


def _bag_seed(path: Path) -> bytes:
    """A ROS 1 bag of two 8x6 frames (rgb8 colour, 16UC1 depth, CameraInfo), written with rosbags' writer."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    t = store.types
    if path.exists():
        path.unlink()
    with Writer(path) as bag:
        image = t["sensor_msgs/msg/Image"]
        rgb = bag.add_connection("/camera/color/image_raw", image.__msgtype__, typestore=store)
        depth = bag.add_connection("/camera/depth/image_raw", image.__msgtype__, typestore=store)
        for i in range(2):
            header = t["std_msgs/msg/Header"](seq=i, stamp=t["builtin_interfaces/msg/Time"](sec=1 + i, nanosec=0),
                                              frame_id="camera")
            for conn, enc, pixels in ((rgb, "rgb8", np.zeros((6, 8, 3), np.uint8)),
                                      (depth, "16UC1", np.full((6, 8), 1000, np.uint16))):
                raw = pixels.view(np.uint8).reshape(-1)
                msg = image(header=header, height=6, width=8, encoding=enc, is_bigendian=0, step=raw.size // 6,
                            data=raw)
                bag.write(conn, (1 + i) * 10**9, store.serialize_ros1(msg, image.__msgtype__))
    return path.read_bytes()


def _tum_index_seed() -> bytes:
    """The three TUM index files of a 2-frame sequence, joined by a separator line (split again by the target)."""
    rgb = "# rgb\n0.000000 rgb/0.000000.png\n0.033333 rgb/0.033333.png\n"
    depth = "# depth\n0.000000 depth/0.000000.png\n0.033333 depth/0.033333.png\n"
    gt = "0.000000 0 0 0 0 0 0 1\n0.033333 0.1 0 0 0 0 0 1\n"
    return "\n===\n".join((rgb, depth, gt)).encode()


# --------------------------------------------------------------------------------------------------
# Targets: bytes -> reader; a SemmapError is a correct refusal
# --------------------------------------------------------------------------------------------------


def _write(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


def target_octomap(data: bytes, folder: Path) -> None:
    from semmap.io.octomap_files import read_octomap

    read_octomap(_write(folder, "x.ot", data))


def target_semmap(data: bytes, folder: Path) -> None:
    from semmap.io.map_info import describe_map_file

    describe_map_file(_write(folder, "x.semmap", data))


def target_ply(data: bytes, folder: Path) -> None:
    from semmap.io.ply import read_ply

    read_ply(_write(folder, "x.ply", data))


def target_trajectory(data: bytes, folder: Path) -> None:
    from semmap.errors import SemmapError
    from semmap.io.trajectory import read_trajectory

    path = _write(folder, "x.txt", data)
    with contextlib.suppress(SemmapError):  # tolerant reading: NaN rows, any order
        read_trajectory(path)
    read_trajectory(path, strict=True)


def target_labelset(data: bytes, folder: Path) -> None:
    from semmap.types import LabelSet

    LabelSet.load(_write(folder, "labelset.json", data))


def target_sevenscenes_pose(data: bytes, folder: Path) -> None:
    from semmap.datasets.sevenscenes import read_pose

    read_pose(_write(folder, "frame-000000.pose.txt", data))


def target_tum_index(data: bytes, folder: Path) -> None:
    """rgb.txt / depth.txt / groundtruth.txt of a sequence whose two frames exist, then every frame read."""
    import cv2

    from semmap.datasets import open_dataset

    seq = folder / "tum"
    for sub in ("rgb", "depth"):
        (seq / sub).mkdir(parents=True, exist_ok=True)
        for stamp in ("0.000000", "0.033333"):
            image = np.zeros((6, 8, 3), np.uint8) if sub == "rgb" else np.full((6, 8), 5000, np.uint16)
            if not (seq / sub / f"{stamp}.png").exists():
                cv2.imwrite(str(seq / sub / f"{stamp}.png"), image)
    parts = data.split(b"\n===\n")
    for name, part in zip(("rgb.txt", "depth.txt", "groundtruth.txt"), [*parts, b"", b""], strict=False):
        (seq / name).write_bytes(part)
    for _ in open_dataset(seq, "tum"):
        pass


def target_scannet_sens(data: bytes, folder: Path) -> None:
    """A scan folder holding only the .sens stream, every frame read."""
    from semmap.datasets.scannet import ScanNetDataset

    scan = folder / "scan"
    scan.mkdir(exist_ok=True)
    (scan / "x.sens").write_bytes(data)
    for _ in ScanNetDataset(scan):
        pass


def target_replica_traj(data: bytes, folder: Path) -> None:
    from semmap.datasets.replica import read_trajectory

    read_trajectory(_write(folder, "traj.txt", data))


def target_rosbag(data: bytes, folder: Path) -> None:
    from semmap.datasets import open_dataset

    for _ in open_dataset(_write(folder, "x.bag", data)):
        pass


TARGETS: dict[str, Callable[[bytes, Path], None]] = {
    "octomap": target_octomap,
    "octomap_bt": target_octomap,
    "semmap": target_semmap,
    "ply": target_ply,
    "trajectory": target_trajectory,
    "labelset": target_labelset,
    "sevenscenes_pose": target_sevenscenes_pose,
    "tum_index": target_tum_index,
    "rosbag": target_rosbag,
    "scannet_sens": target_scannet_sens,
    "replica_traj": target_replica_traj,
}


def run_target(name: str, data: bytes, folder: Path) -> None:
    """One input through one target: a result or a SemmapError pass; any other exception propagates."""
    from semmap.errors import SemmapError

    with contextlib.suppress(SemmapError):
        TARGETS[name](data, folder)


# --------------------------------------------------------------------------------------------------
# atheris driver
# --------------------------------------------------------------------------------------------------
def fuzz_one(name: str, runs: int, corpus: Path | None) -> None:
    """Run atheris on one target for ``runs`` inputs (this process ends when atheris does, with libFuzzer's exit
    code: 0 when every input passed)."""
    import atheris

    folder = Path(tempfile.mkdtemp(prefix=f"semmap-fuzz-{name}-"))
    corpus = corpus or folder / "corpus"
    corpus.mkdir(parents=True, exist_ok=True)
    seed = seed_files(folder / "seeds")[name]
    (corpus / "seed").write_bytes(seed)
    logging_off()
    # the seed first: it imports the reader's modules and compiles their numba kernels from the original bytecode
    # (instrumented bytecode does not compile); then semmap's plain Python functions are instrumented for coverage
    run_target(name, seed, folder)
    instrumented = instrument_semmap(atheris)

    print(json.dumps({"instrumented_functions": instrumented}), flush=True)

    def test_one_input(data: bytes) -> None:
        run_target(name, data, folder)

    atheris.Setup([sys.argv[0], f"-runs={runs}", "-timeout=30", str(corpus)], test_one_input)
    atheris.Fuzz()


def instrument_semmap(atheris) -> int:
    """Instrument every plain Python function and method of the loaded semmap modules (not numba dispatchers, not
    other packages: instrumenting all 20,000 loaded functions takes minutes); returns how many."""
    import inspect
    import types

    done = 0
    for module_name, module in list(sys.modules.items()):
        if not module_name.startswith("semmap") or module is None:
            continue
        for value in list(vars(module).values()):
            candidates = [value]
            if inspect.isclass(value) and value.__module__ == module_name:
                candidates = [v for v in vars(value).values() if isinstance(v, types.FunctionType)]
            for fn in candidates:
                if isinstance(fn, types.FunctionType) and fn.__module__ == module_name:
                    atheris.instrument_func(fn)
                    done += 1
    return done


def logging_off() -> None:
    """Readers warn about bad frames; thousands of inputs would flood the terminal."""
    import logging

    logging.getLogger("semmap").setLevel(logging.CRITICAL)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("target", nargs="?", default="all", help=f"one of {', '.join(TARGETS)}, or all")
    ap.add_argument("--runs", type=int, default=5000, help="inputs per target")
    ap.add_argument("--corpus", type=Path, help="corpus folder (kept between runs)")
    ap.add_argument("--list", action="store_true", help="list the targets and exit")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.list:
        print("\n".join(TARGETS))
        return
    if args.child:
        fuzz_one(args.target, args.runs, args.corpus)
        return
    names = list(TARGETS) if args.target == "all" else [args.target]
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        raise SystemExit(f"unknown target {unknown[0]!r}; known: {', '.join(TARGETS)}")
    total = 0
    for name in names:  # atheris.Fuzz() never returns: one child process per target
        command = [sys.executable, __file__, name, "--child", "--runs", str(args.runs)]
        if args.corpus:
            command += ["--corpus", str(args.corpus / name)]
        r = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        done = re.search(r"Done (\d+) runs in (\d+) second", r.stderr)
        instrumented = re.search(r'"instrumented_functions": (\d+)', r.stdout)
        result = {"target": name, "inputs": int(done.group(1)) if done else None,
                  "seconds": int(done.group(2)) if done else None,
                  "instrumented_functions": int(instrumented.group(1)) if instrumented else None,
                  "crashed": r.returncode != 0}
        if r.returncode != 0:
            result["stderr_tail"] = "".join(io.StringIO(r.stderr).readlines()[-25:])
        total += result["inputs"] or 0
        print(json.dumps(result), flush=True)
    print(json.dumps({"targets": len(names), "inputs": total}), flush=True)


if __name__ == "__main__":
    main()
