"""Do a 7-Scenes sequence's colour and depth images come from the same instant? Counts the frames whose colour
or depth file repeats the previous frame's exactly (a stream that delivered no new image), and lists the frames
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

    python scripts/seven_scenes_stream_check.py [../shared/data/7scenes-redkitchen] [--stride 1]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets import open_dataset
from semmap.datasets.sevenscenes import find_frames
from semmap.eval.registration import edge_misalignment
from semmap.geometry import register_color

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "7scenes-redkitchen"


def repeats(paths: list[Path]) -> np.ndarray:
    """Per frame, whether its image file decodes to exactly the previous frame's image (False for the first)."""
    out = np.zeros(len(paths), bool)
    previous = None
    for i, path in enumerate(paths):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise SystemExit(f"{path}: cannot read the image")
        out[i] = previous is not None and previous.shape == image.shape and np.array_equal(previous, image)
        previous = image
    return out


def pairing_distances(sequence: Path, stride: int) -> np.ndarray:
    """(frames, 3): mean distance from frame i's depth outlines to the colour edges of frame i-1, i, i+1's raw colour
    image registered at frame i's depth (NaN where that frame does not exist or is not evaluated)."""
    frames = list(open_dataset(sequence, "7scenes"))
    if not frames or frames[0].raw_color is None:
        raise SystemExit(f"{sequence}: colour is not registered for this camera, so there is no pairing to test")
    out = np.full((len(frames), 3), np.nan)
    for i in range(0, len(frames), stride):
        depth = frames[i].depth
        for k, j in enumerate((i - 1, i, i + 1)):
            if 0 <= j < len(frames):
                raw = frames[j].raw_color
                out[i, k] = edge_misalignment(register_color(raw.image, depth, frames[i].intrinsics, raw.camera), depth)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SHARED), help="7-Scenes sequence folder")
    parser.add_argument("--stride", type=int, default=1, help="test the pairing on every k-th frame")
    args = parser.parse_args()
    refs = find_frames(Path(args.sequence))
    if not refs:
        raise SystemExit(f"{args.sequence}: no frame-N.color.* files")
    colour = repeats([r.color for r in refs])
    depth = repeats([r.sibling(".depth.png") for r in refs])
    shift = np.cumsum(depth.astype(int) - colour.astype(int))
    names = [r.name for r in refs]
    print(f"{len(refs)} frames: depth repeats {int(depth.sum())}, colour repeats {int(colour.sum())}, "
          f"both {int((depth & colour).sum())}")
    print("depth only:", ", ".join(names[i] for i in np.flatnonzero(depth & ~colour)) or "none")
    print("colour only:", ", ".join(names[i] for i in np.flatnonzero(colour & ~depth)) or "none")
    print(f"frames whose streams are shifted against the first frame's pairing: {int((shift != 0).sum())}")
    distances = pairing_distances(Path(args.sequence), max(1, args.stride))
    fresh = ~colour & ~depth  # both images new: the pairing is what is tested
    pairing = {}
    for label, chosen in (("in_sync", fresh & (shift == 0)), ("shifted", fresh & (shift != 0))):
        rows = distances[chosen & ~np.isnan(distances).any(axis=1)]
        pairing[label] = {"frames": len(rows), **{f"offset_{o:+d}_px": round(float(rows[:, k].mean()), 3)
                                                   for k, o in enumerate((-1, 0, 1))}} if len(rows) else {"frames": 0}
        if len(rows):
            print(f"{label:8s} ({len(rows)} frames): depth outline to colour edge of frame i-1 / i / i+1: "
                  + " / ".join(f"{d:.2f}" for d in rows.mean(axis=0)) + " px")
    print(json.dumps({"check": "7scenes-streams", "frames": len(refs), "depth_repeats": int(depth.sum()),
                      "colour_repeats": int(colour.sum()), "both": int((depth & colour).sum()),
                      "depth_only": int((depth & ~colour).sum()), "colour_only": int((colour & ~depth).sum()),
                      "shifted_frames": int((shift != 0).sum()), "pairing_edge_distance": pairing}))


if __name__ == "__main__":
    main()
