"""Copy the shipped training runs' best checkpoints into weights/ and write weights/manifest.json.

For every network: the file's sha256 and size, the architecture, the exact training command, the data (scene
seeds of scripts/make_training_data.py), the validation scores of the kept checkpoint and, given the JSON line
of benchmarks/bench_networks.py (--bench), the held-out test scores and timings.  With --bench the manifest also
names the demo's network: the best test MIoU per millisecond (ONNX Runtime, 640x480 frame).  With --calibrated,
the file shipped is the run's best checkpoint as scripts/calibrate_weights.py recalibrated it (``<network>.pt``
in that folder; its calibration record goes into the manifest).

    .venv/bin/python scripts/ship_weights.py --runs outputs/train-runs [--bench outputs/bench-networks.json] \
        [--calibrated outputs/calibrated]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
from pathlib import Path

from semmap.files.atomic import write_text_atomic
from semmap.perception.networks.registry import load_weights
from semmap.perception.registry import MANIFEST, TRAINED_NETWORKS, shipped_weights_dir
from semmap.train.sim_data import PATH_SECONDS, TRAIN_FRAMES, VAL_FRAMES, train_plan, val_plan

#: Largest shipped weight file (bytes).
MAX_BYTES = 10 * 1024 * 1024
TEST_SCENES = "scene seeds 0-3 (office, kitchen, living_room, bedroom; medium; loop of 300 frames), 640x480"
#: The data of the shipped runs (scripts/train_shipped.sh).
DEFAULT_DATA_COMMAND = "python scripts/make_training_data.py --out outputs/train-data-320 --image-size 320x240"


def command(config: dict) -> str:
    """The ``semmap train`` command line a run folder's config.json records."""
    w, h = config["input_size"]
    return (f"semmap train --model {config['model']} --data {' --data '.join(config['data'])} "
            f"--val {' --val '.join(config['val'])} --out {config['out']} --iterations {config['iterations_total']} "
            f"--batch {config['batch']} --lr {config['lr']:g} --input-size {w}x{h} --width {config['width']:g} "
            f"--resnet-depth {config['depth']} --seed {config['seed']} --threads {config['threads']} "
            f"--eval-every {config['eval_every']}"
            + (f" --init {config['init']}" if config.get("init") else "")
            + (f" --backbone {config['backbone']}" if config.get("backbone") not in (None, "resnet") else ""))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, default=Path("outputs/train-runs"))
    parser.add_argument("--bench", type=Path, default=None, help="JSON line of benchmarks/bench_networks.py")
    parser.add_argument("--networks", default=None, help="comma-separated networks to ship from --runs; the other "
                        "entries of the manifest are kept as they are (default: all, manifest rewritten)")
    parser.add_argument("--calibrated", type=Path, default=None, help="folder of <network>.pt: the runs' best "
                        "checkpoints recalibrated by scripts/calibrate_weights.py, shipped instead of best.pt")
    parser.add_argument("--data-command", default=None, help="the make_training_data.py command of these runs' data, "
                        "recorded per network (when it differs from the manifest's)")
    args = parser.parse_args()
    out = shipped_weights_dir()
    out.mkdir(parents=True, exist_ok=True)
    bench = json.loads(args.bench.read_text().strip().splitlines()[-1]) if args.bench else None
    old_manifest = json.loads((out / MANIFEST).read_text()) if (out / MANIFEST).is_file() else {}
    only = None if args.networks is None else {n.strip() for n in args.networks.split(",")}
    networks = {} if only is None else dict(old_manifest.get("networks", {}))
    for name in (n for n in TRAINED_NETWORKS if only is None or n in only):
        run = args.runs / name
        if not (run / "final.pt").is_file():
            print(f"{name}: no finished run in {run}; not shipped")
            continue
        target = out / f"{name}.pt"
        source = run / "best.pt" if args.calibrated is None else args.calibrated / f"{name}.pt"
        if not source.is_file():
            raise SystemExit(f"{source}: no such weight file")
        shutil.copyfile(source, target)
        data = target.read_bytes()
        if len(data) > MAX_BYTES:
            raise SystemExit(f"{target}: {len(data)} bytes exceeds the {MAX_BYTES} byte limit")
        loaded = load_weights(target)
        config = json.loads((run / "config.json").read_text())
        log = json.loads((run / "log.json").read_text())
        entry = {"file": target.name, "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data),
                 "network": loaded.spec.describe(), "spec": loaded.spec.to_dict(),
                 "parameters": loaded.meta.get("parameters"), "input_size": list(loaded.input_size),
                 "command": command(config),
                 "best_iteration": loaded.meta.get("iteration"), "validation": loaded.meta.get("metrics"),
                 "train_seconds": log["rows"][-1]["seconds"], "train_images": config["train_images"],
                 "val_images": config["val_images"], "init": config.get("init") or "scratch",
                 "temperature": loaded.meta.get("temperature", 1.0)}
        if "calibration" in loaded.meta:  # fitted after training (scripts/calibrate_weights.py), with where
            entry["calibration"] = loaded.meta["calibration"]
        if args.data_command:
            entry["data_command"] = args.data_command
        if bench is not None:
            rows = [r for r in bench["results"] if r["network"] == name]
            entry["test"] = {r["runtime"]: {k: r.get(k) for k in ("miou", "mpa", "pixel_accuracy", "miou_shared",
                                                                   "ms_per_frame", "agreement_with_torch", "ece",
                                                                   "nll", "ece_uncalibrated", "nll_uncalibrated")
                                            if k in r}
                             for r in rows}
        networks[name] = entry
        print(f"{name}: {entry['network']}, {len(data) / 1e6:.2f} MB, val mIoU {entry['validation']['val_miou']}")
    manifest = {
        "about": "Segmentation networks trained by semmap on simulated scenes (CPU, see docs/DESIGN.md); "
                 "regenerate with scripts/make_training_data.py, scripts/train_shipped.sh, scripts/ship_weights.py",
        "data": {"train": {"scene_seeds": [p[0] for p in train_plan()], "frames_per_scene": TRAIN_FRAMES,
                           "path_seconds": PATH_SECONDS,
                           "scenes": [scene.name for scene in train_plan()]},
                 "val": {"scene_seeds": [p[0] for p in val_plan()], "frames_per_scene": VAL_FRAMES,
                         "path_seconds": PATH_SECONDS},
                 "test": TEST_SCENES,
                 "generate": args.data_command or DEFAULT_DATA_COMMAND},
        "networks": networks,
    }
    if "external" in old_manifest:  # the shipped weights semmap did not train (ESPNetv2), kept as they are
        manifest["external"] = old_manifest["external"]
    if only is not None:  # the data section describes the networks kept from before
        manifest["data"] = old_manifest.get("data", manifest["data"])
    if bench is not None and only is None:
        onnx = {n: e["test"]["onnx"] for n, e in networks.items() if "onnx" in e.get("test", {})}
        best = max(onnx, key=lambda n: onnx[n]["miou"] / onnx[n]["ms_per_frame"])
        manifest["demo"] = {"network": best, "rule": "highest test MIoU per ms (ONNX Runtime, 640x480 frame)",
                            "miou": onnx[best]["miou"], "ms_per_frame": onnx[best]["ms_per_frame"],
                            "bench_frames": bench["frames"], "bench_threads": bench["threads"]}
        print(f"demo network: {best}")
    elif "demo" in old_manifest:  # keep an earlier choice when only re-copying
        manifest["demo"] = old_manifest["demo"]
    write_text_atomic(out / MANIFEST, json.dumps(manifest, indent=1) + "\n")


if __name__ == "__main__":
    from semmap.cli.terminal import exit_on_errors

    exit_on_errors(main, "ship_weights")  # a bad file or option: one line, not a traceback
