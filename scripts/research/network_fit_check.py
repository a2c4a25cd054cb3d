"""Does a trained network under-fit or fail to generalise? (issue 32)

Scores a weight file (a run's ``best.pt`` or a shipped ``weights/*.pt``) on every ``--every``-th image of its
training folder and on the validation folder, at the training size and without augmentation, the way the
trainer validates. Training MIoU near the validation MIoU says the network or the schedule is too small; a wide
gap says the scenes are too few.

    python scripts/research/network_fit_check.py outputs/runs-320/pspnet/best.pt \
        [--train outputs/train-data-320/train] [--val outputs/train-data-320/val] [--every 10]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from semmap.eval.semantic import confusion, scores
from semmap.perception.networks.registry import load_weights
from semmap.train.calibrate import image_logits
from semmap.train.class_weights import IGNORE
from semmap.train.data import gather


def every_nth(n: int, every: int) -> np.ndarray:
    """Indices 0, every, 2 every, ... below n (every >= 1)."""
    if every < 1:
        raise ValueError(f"--every must be at least 1, got {every}")
    return np.arange(0, n, every)


def folder_scores(net, folder: Path, every: int) -> dict:
    """MIoU and pixel accuracy of ``net`` (a loaded weight file) on every ``every``-th image of ``folder``."""
    ds = gather([folder], net.input_size, label_set=net.label_set, need_depth=net.spec.uses_depth)
    k = len(net.label_set)
    conf = np.zeros((k, k), np.int64)
    picked = every_nth(len(ds), every)
    for i, logits in image_logits(net, ds, picked):
        conf += confusion(logits.argmax(1).numpy(), ds.labels[i:i + 1].astype(np.int64), k, ignore=IGNORE)
    sc = scores(conf, ignore=IGNORE)
    return {"images": len(picked), "miou": round(sc.miou, 4), "pixel_accuracy": round(sc.accuracy, 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("weights", type=Path)
    parser.add_argument("--train", type=Path, default=Path("outputs/train-data-320/train"))
    parser.add_argument("--val", type=Path, default=Path("outputs/train-data-320/val"))
    parser.add_argument("--every", type=int, default=10, help="score every N-th training image")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    net = load_weights(args.weights)
    row = {"weights": str(args.weights), "network": net.spec.describe(),
           "train": folder_scores(net, args.train, args.every), "val": folder_scores(net, args.val, 1)}
    row["gap_points"] = round(100 * (row["train"]["miou"] - row["val"]["miou"]), 1)
    print(f"{row['network']}: training scenes MIoU {row['train']['miou']} ({row['train']['images']} images), "
          f"validation scenes {row['val']['miou']} ({row['val']['images']}): gap {row['gap_points']} points")
    print(json.dumps(row))


if __name__ == "__main__":
    main()
