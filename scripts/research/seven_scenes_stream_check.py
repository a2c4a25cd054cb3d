"""Do a 7-Scenes sequence's colour and depth images come from the same instant? Counts the frames whose colour
or depth image repeats the previous frame's exactly (a stream that delivered no new image), and lists the frames
where only one of the two repeats.

The Kinect's colour and depth streams are not synchronised; a recorder pairing the latest image of each repeats
one when it polls faster than that stream. Where the colour repeats and the depth does not (or the reverse), the
two images of that frame are about one frame period (33 ms) apart, and the photometric and geometric costs
of a tracker then describe different camera poses. The running count of depth-only repeats minus colour-only
ones shows for how long the two streams stay shifted against their pairing at the start.

Whether they really are shifted is then tested on the images themselves: each frame's depth outlines are put on
the colour edges of the previous, the same and the next frame's raw colour image (registered at this frame's
depth, as the reader does), and the mean distance (pixels, ``semmap.eval.registration``) is reported per
pairing offset, separately for frames the repeat count calls in sync and shifted. The offset the colour really
has gives the smallest distance; a one-frame shift of a moving camera costs about half a pixel.

    python scripts/research/seven_scenes_stream_check.py [../shared/data/7scenes-redkitchen] [--stride 1]
"""

from __future__ import annotations

import argparse
import json
from collections import deque
from pathlib import Path

import numpy as np

from semmap.datasets import open_dataset
from semmap.eval.registration import edge_misalignment
from semmap.geometry import register_color
from semmap.types import Frame

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "7scenes-redkitchen"
OFFSETS = (-1, 0, 1)


def _colour(frame: Frame) -> np.ndarray:
    """The colour image as the camera took it (the raw one where the reader registered colour)."""
    return frame.rgb if frame.raw_color is None else frame.raw_color.image


def _pairing(window: list[Frame], centre: int) -> list[float]:
    """Mean distance from ``window[centre]``'s depth outlines to the colour edges of the previous, its own and the
    next frame's raw colour, registered at its depth (NaN where the window has no such frame)."""
    frame = window[centre]
    out = []
    for offset in OFFSETS:
        j = centre + offset
        if 0 <= j < len(window):
            raw = window[j].raw_color
            registered = register_color(raw.image, frame.depth, frame.intrinsics, raw.camera)
            out.append(edge_misalignment(registered, frame.depth))
        else:
            out.append(float("nan"))
    return out


def scan(sequence: Path, stride: int) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray | None]:
    """One pass over the sequence, three frames in memory: frame names, colour and depth repeats (the image equals
    the previous frame's exactly), and per frame the pairing distances of :func:`_pairing` for every ``stride``-th
    frame (NaN rows elsewhere; None when the reader does not register this camera's colour)."""
    names: list[str] = []
    colour: list[bool] = []
    depth: list[bool] = []
    distances: list[list[float]] = []
    window: deque[Frame] = deque(maxlen=3)  # frames i-1, i, i+1 once full
    registered = True
    for frame in open_dataset(sequence, "7scenes"):
        previous = window[-1] if window else None
        names.append(frame.name or str(frame.index))
        colour.append(previous is not None and np.array_equal(_colour(previous), _colour(frame)))
        depth.append(previous is not None and np.array_equal(previous.depth, frame.depth))
        registered = registered and frame.raw_color is not None
        window.append(frame)
        i = len(names) - 2  # the frame whose next one just arrived
        if registered and i >= 0:
            distances.append(_pairing(list(window), len(window) - 2) if i % stride == 0 else [np.nan] * 3)
    if not names:
        raise SystemExit(f"{sequence}: no frames")
    if registered:  # the last frame has no next one
        distances.append(_pairing(list(window), len(window) - 1) if (len(names) - 1) % stride == 0
                         else [np.nan] * 3)
    return names, np.array(colour), np.array(depth), np.array(distances) if registered else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SHARED), help="7-Scenes sequence folder")
    parser.add_argument("--stride", type=int, default=1, help="test the pairing on every k-th frame")
    args = parser.parse_args()
    names, colour, depth, distances = scan(Path(args.sequence), max(1, args.stride))
    shift = np.cumsum(depth.astype(int) - colour.astype(int))
    print(f"{len(names)} frames: depth repeats {int(depth.sum())}, colour repeats {int(colour.sum())}, "
          f"both {int((depth & colour).sum())}")
    print("depth only:", ", ".join(names[i] for i in np.flatnonzero(depth & ~colour)) or "none")
    print("colour only:", ", ".join(names[i] for i in np.flatnonzero(colour & ~depth)) or "none")
    print(f"frames whose streams are shifted against the first frame's pairing: {int((shift != 0).sum())}")
    pairing = {}
    if distances is None:
        print("colour is not registered for this camera: the pairing is not tested")
    else:
        fresh = ~colour & ~depth  # both images new: the pairing is what is tested
        for label, chosen in (("in_sync", fresh & (shift == 0)), ("shifted", fresh & (shift != 0))):
            rows = distances[chosen & ~np.isnan(distances).any(axis=1)]
            pairing[label] = {"frames": len(rows), **{f"offset_{o:+d}_px": round(float(rows[:, k].mean()), 3)
                                                       for k, o in enumerate(OFFSETS)}} if len(rows) else {"frames": 0}
            if len(rows):
                print(f"{label:8s} ({len(rows)} frames): depth outline to colour edge of frame i-1 / i / i+1: "
                      + " / ".join(f"{d:.2f}" for d in rows.mean(axis=0)) + " px")
    print(json.dumps({"check": "7scenes-streams", "frames": len(names), "depth_repeats": int(depth.sum()),
                      "colour_repeats": int(colour.sum()), "both": int((depth & colour).sum()),
                      "depth_only": int((depth & ~colour).sum()), "colour_only": int((colour & ~depth).sum()),
                      "shifted_frames": int((shift != 0).sum()), "pairing_edge_distance": pairing}))


if __name__ == "__main__":
    main()
