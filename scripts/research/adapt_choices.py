"""(issue 46) How `semmap adapt`'s pseudo-labels and training settings were chosen, on a development scene's
pseudo-labelled frames (a `semmap adapt` output folder's pseudo_labels.npz, from a simulated run with true labels).

``teachers``: on every 10th frame, the pixel accuracy and MIoU against the true labels of the pseudo-labels as
kept, of the network on the same pixels, of the map before masking, and of variants: without the depth-edge mask,
with the network's confident labels vetoing the map's (threshold 0.7-0.95) or replacing them.

``variants``: the adaptation itself from the same frames under other settings (class weights, frozen BatchNorm,
which labels, learning rate), each for ``--steps`` steps, printing each evaluation's held-out MIoU against the map
and against the true labels and the validation MIoU.

    python scripts/research/adapt_choices.py teachers ADAPT_DIR [--weights weights/fcn.pt]
    python scripts/research/adapt_choices.py variants ADAPT_DIR --out DIR [--steps 60] [--only base,uniform]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from semmap.eval.semantic import confusion, scores
from semmap.perception.registry import shipped_weights
from semmap.train import adapt as adapt_lib
from semmap.train.trainable import load_trainable
from semmap.train.trainer import normalise
from semmap.types import Trajectory

#: The variants of ``variants``: settings, which labels ("kept": as masked then; "mapnet": the map's labels
#: without the edge mask, vetoed where the network is at least 0.7 sure of another class).
VARIANTS = {
    "base": ({"class_weighting": True, "lr": 0.005}, "kept"),
    "freeze": ({"class_weighting": True, "freeze_norm": True, "lr": 0.005}, "kept"),
    "uniform": ({"class_weighting": False, "lr": 0.005}, "kept"),
    "uniform_mapnet": ({"class_weighting": False, "lr": 0.005}, "mapnet"),
    "uniform_mapnet_lr01": ({"class_weighting": False, "lr": 0.01}, "mapnet"),
}


def network_top(model, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(class, probability) of each pixel of the (N, H, W, 3) images."""
    preds, confs = [], []
    model.eval()
    with torch.no_grad():
        for i in range(len(rgb)):
            x = torch.from_numpy(rgb[i:i + 1]).permute(0, 3, 1, 2).float() / 255
            logits, _ = model.forward_train(normalise(x))
            c, a = torch.softmax(logits[0], 0).max(0)
            preds.append(a.numpy())
            confs.append(c.numpy())
    return np.stack(preds), np.stack(confs)


def teachers(folder: Path, weights: Path) -> None:
    z = np.load(folder / adapt_lib.DATA_FILE)
    net = load_trainable("fcn", weights)
    k = len(net.label_set)
    idx = np.arange(0, len(z["rgb"]), 10)
    pred, conf = network_top(net.model, z["rgb"][idx])
    truth, kept_l, mapped_l = z["truth"][idx], z["labels"][idx], z["map_labels"][idx]
    labelled = truth > 0
    kept, mapped = labelled & (kept_l > 0), labelled & (mapped_l > 0)

    def row(name: str, labels: np.ndarray, mask: np.ndarray) -> None:
        s = scores(confusion(labels[mask], truth[mask], k))
        print(f"{name:52s} cover {mask.sum() / labelled.sum():.3f}  accuracy {s.accuracy:.3f}  MIoU {s.miou:.3f}")

    row("network, every labelled pixel", pred, labelled)
    row("map before masking", mapped_l, mapped)
    row("pseudo-labels as kept", kept_l, kept)
    row("  network on the same pixels", pred, kept)
    for tau in (0.7, 0.8, 0.9, 0.95):
        sure = conf >= tau
        v = kept & ~(sure & (pred != kept_l))
        row(f"kept, vetoed where the network is >= {tau} sure", kept_l, v)
        row("  network on the same pixels", pred, v)
        row(f"kept, the network's label where >= {tau} sure", np.where(sure, pred, kept_l), kept)
        v = mapped & ~(sure & (pred != mapped_l))
        row(f"no edge mask, vetoed where >= {tau} sure", mapped_l, v)
        row("  network on the same pixels", pred, v)


def variants(folder: Path, weights: Path, out: Path, steps: int, only: list[str] | None) -> None:
    class _Map:
        resolution = 0.05
        label_set = load_trainable("fcn", weights).label_set

    for name, (settings, labels) in VARIANTS.items():
        if only and name not in only:
            continue

        class Dev(adapt_lib.Adapter):
            def _make_data(self, labels=labels):
                z = np.load(folder / adapt_lib.DATA_FILE)
                taught = z["labels"].copy() if labels == "kept" else z["map_labels"].copy()
                if labels == "mapnet":
                    pred, conf = network_top(self.net.model, z["rgb"])
                    taught[(conf >= 0.7) & (pred != taught)] = 0
                return self._split(z["rgb"], taught, None, z["map_labels"], z["truth"], z["holdout"].astype(bool),
                                   [str(n) for n in z["names"]], json.loads(str(z["stats"])))

        source = adapt_lib.AdaptSource(run_dir=folder, frames=lambda: iter(()), length=0,
                               trajectory=Trajectory(np.zeros(0), np.zeros((0, 4, 4))), map=_Map(), weights=weights,
                               segmenter="fcn", min_depth=0.1, max_depth=5.0)
        every = max(1, steps // 3)
        result = Dev(source, adapt_lib.AdaptSettings(out=out / name, steps=steps, eval_every=every, threads=1,
                                                     **settings)).run()
        for r in result.report["rows"]:
            print(name, {key: r.get(key) for key in ("step", "holdout_pseudo_miou", "holdout_truth_miou", "val_miou",
                                                     "pseudo_loss", "replay_loss")}, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("teachers", "variants"))
    ap.add_argument("adapt_dir", type=Path, help="a semmap adapt output folder (its pseudo_labels.npz)")
    ap.add_argument("--weights", type=Path, default=shipped_weights("fcn"))
    ap.add_argument("--out", type=Path, default=Path("outputs/adapt-choices"))
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--only", default=None, help=f"comma-separated variants of {', '.join(VARIANTS)}")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.what == "teachers":
        teachers(args.adapt_dir, args.weights)
    else:
        variants(args.adapt_dir, args.weights, args.out, args.steps, args.only.split(",") if args.only else None)


if __name__ == "__main__":
    main()
