"""Fit the calibration temperature of a trained network's weight file on validation folders and write a copy
that carries it (``meta.temperature``, applied by the segmenter unless ``--no-calibration``).  Networks trained
by ``semmap train`` since the temperature was added already carry one (fitted at every validation); this is for
older files, e.g. the shipped scratch networks:

    .venv/bin/python scripts/calibrate_weights.py --weights weights/pspnet.pt --val outputs/train-data/val \\
        --out outputs/pspnet-calibrated.pt
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from semmap.train.calibrate import calibrate_weights


def main(argv: list[str] | None = None) -> None:
    """Fit, write, print the record as JSON."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--weights", type=Path, required=True)
    parser.add_argument("--val", type=Path, action="append", required=True, help="validation folder (repeatable)")
    parser.add_argument("--out", type=Path, required=True, help="the calibrated copy to write")
    args = parser.parse_args(argv)
    print(json.dumps(calibrate_weights(args.weights, args.val, args.out)))


if __name__ == "__main__":
    main()
