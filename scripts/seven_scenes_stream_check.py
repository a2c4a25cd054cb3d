"""Do a 7-Scenes sequence's colour and depth images come from the same instant? Counts the frames whose colour
or depth file repeats the previous frame's exactly (a stream that delivered no new image), and lists the frames
where only one of the two repeats.

The Kinect's colour and depth streams are not synchronised; a recorder pairing the latest image of each repeats
one when it polls faster than that stream. Where the colour repeats and the depth does not (or the reverse), the
two images of that frame are about one frame period (33 ms) apart, and the photometric and geometric costs
of a tracker then describe different camera poses. The running count of depth-only repeats minus colour-only
ones shows for how long the two streams stay shifted against their pairing at the start.

    python scripts/seven_scenes_stream_check.py [../shared/data/7scenes-redkitchen]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets.sevenscenes import find_frames

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SHARED), help="7-Scenes sequence folder")
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
    print(json.dumps({"check": "7scenes-streams", "frames": len(refs), "depth_repeats": int(depth.sum()),
                      "colour_repeats": int(colour.sum()), "both": int((depth & colour).sum()),
                      "depth_only": int((depth & ~colour).sum()), "colour_only": int((colour & ~depth).sum()),
                      "shifted_frames": int((shift != 0).sum())}))


if __name__ == "__main__":
    main()
