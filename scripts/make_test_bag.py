"""Write a small ROS bag from any sequence semmap reads (e.g. a ``semmap simulate`` folder), to try the bag reader
without a robot: colour, depth (16UC1, millimetres), CameraInfo and the poses on /tf (map -> odom -> base_link,
base_link -> camera on /tf_static), with the topic names of a RealSense driver. It uses the writer of the reader's
tests (tests/ros_helpers.py, rosbags' own writers), so run it from a checkout:

    .venv/bin/semmap simulate --out sim/tiny --frames 10 --image-size 320x240
    .venv/bin/python scripts/make_test_bag.py sim/tiny --out outputs/tiny.bag                  # ROS 1
    .venv/bin/python scripts/make_test_bag.py sim/tiny --out outputs/tiny-bag2 --kind mcap     # ROS 2 (or sqlite3)
    .venv/bin/semmap run outputs/tiny.bag --out outputs/bag-run --semantics none
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # ros_helpers: the bag writer of the tests

from ros_helpers import write_bag  # noqa: E402
from semmap.datasets import open_dataset  # noqa: E402
from semmap.errors import SemmapError  # noqa: E402

KINDS = ("ros1", "sqlite3", "mcap")


def make_bag(sequence: Path, out: Path, *, kind: str = "ros1", max_frames: int | None = None) -> int:
    """Write the frames of ``sequence`` (with poses) into the bag ``out``; returns the frames written. Refuses an
    ``out`` that exists (a bag is never overwritten) and a sequence without poses (the bag's /tf would be empty)."""
    if out.exists():
        raise SemmapError(f"{out}: exists; name a new bag file (ROS 1) or folder (ROS 2)")
    frames = [f for f in open_dataset(sequence, max_frames=max_frames) if f.T_world_cam is not None]
    if not frames:
        raise SemmapError(f"{sequence}: no frame with a pose to write")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_bag(out, frames, kind=kind)
    return len(frames)


def main(argv: list[str] | None = None) -> int:
    """The command line; exit code 1 with one line on bad input."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequence", type=Path, help="a sequence semmap reads (TUM folder, semmap simulate output, ...)")
    ap.add_argument("--out", type=Path, required=True, help="the bag: a .bag file (ros1) or a new folder (ROS 2)")
    ap.add_argument("--kind", choices=KINDS, default="ros1", help="ROS 1 bag, or ROS 2 with sqlite3 / mcap storage")
    ap.add_argument("--max-frames", type=int, default=None, help="write only the first N frames")
    args = ap.parse_args(argv)
    try:
        n = make_bag(args.sequence, args.out, kind=args.kind, max_frames=args.max_frames)
    except SemmapError as exc:
        print(f"make_test_bag: error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {n} frames to {args.out} (map it with: .venv/bin/semmap run {args.out} --out OUT)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
