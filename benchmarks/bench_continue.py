"""``semmap run SEQ --continue PRIOR`` measured on the simulator: how well a second recording is aligned to a prior
map, and whether the continued map equals the map of both recordings made in one run.

A prior is mapped from one recording of a simulated scene (ground-truth poses, the frames' own labels, OctoMap
plus the fine point map whose surface the alignment's ICP uses). Second recordings of the same scene take other
camera paths (``trajectory_seed`` 1..N: they start anywhere in the scene); each is given to the alignment with its
poses re-expressed in its own first camera's frame, as a tracker would give them, so the alignment has to find
the whole transform; its error is the distance of the estimated transform from the true one (the recording's
first ground-truth pose). Then ``run_config(..., continue_from=prior)`` maps one second recording into the prior,
and its OctoMap is compared cell by cell with the OctoMap of both recordings mapped in one run with ground-truth
poses: a known cell agrees when both maps hold it in the same state (free / occupied) and, occupied, with the same
top class.

    PYTHONPATH=src python benchmarks/bench_continue.py [--quick] [--starts N]

Last line: {"bench": "continue", "aligned_within_2cm_1deg": fraction, "starts": N, "errors": [...],
"cells_agree": fraction, "occupied_agree": fraction, ...}
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig, SemanticSource
from semmap.datasets.simulated import SimulatedDataset
from semmap.io.map_files import load_map
from semmap.keys import keys_to_coords, unpack_keys
from semmap.localization.align import align_recording
from semmap.localization.prior import prior_from_octomap
from semmap.maps.registry import MapKind
from semmap.pipeline import semantics_for
from semmap.runner import run_config
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import DEFAULT_INTRINSICS, invert_pose, pose_change

POS_TOL_M, ROT_TOL_DEG = 0.02, 1.0


class Recording(SimulatedDataset):
    """A simulated recording whose poses are given in another frame (``T_new_world`` @ ground truth) and whose
    frames are numbered from ``first_index``."""

    def __init__(self, *args, T_new_world: np.ndarray | None = None, first_index: int = 0, **kw) -> None:
        super().__init__(*args, **kw)
        self.T_new_world = np.eye(4) if T_new_world is None else T_new_world
        self.first_index = first_index

    def __iter__(self):
        for f in super().__iter__():
            i = f.index + self.first_index
            yield replace(f, T_world_cam=self.T_new_world @ f.T_world_cam, index=i, name=f"{i:06d}",
                          timestamp=i / 30.0)


class Both:
    """Two recordings one after the other (the one-run reference)."""

    def __init__(self, a: SimulatedDataset, b: SimulatedDataset) -> None:
        self.a, self.b = a, b
        self.name, self.intrinsics, self.label_set, self.skipped = "both", a.intrinsics, a.label_set, []

    def __len__(self) -> int:
        return len(self.a) + len(self.b)

    def __iter__(self):
        yield from self.a
        yield from self.b


def config(out: Path, name: str, res: float, maps: tuple[MapKind, ...]) -> RunConfig:
    """A run with ground-truth poses and the frames' own labels."""
    return RunConfig(input=InputConfig(dataset=Path(name)), mapping=MappingConfig(resolution=res, maps=maps),
                     semantics=SemanticsConfig(source=SemanticSource.LABELS),
                     output=OutputConfig(out=out, preview=False, plots=False))


def recording(scene, seed: int, frames: int, stride: int, intr, *, first_index: int = 0, relative: bool = True):
    poses = make_trajectory(scene, "walk", frames * stride, seed=seed)[::stride]
    T = invert_pose(poses[0]) if relative else np.eye(4)
    return Recording(scene, poses, seed=seed, intrinsics=intr, name=f"rec{seed}", T_new_world=T,
                     first_index=first_index), poses[0]


def cell_agreement(a, b) -> tuple[float, float]:
    """Share of the union of known cells in the same state (free / occupied, and top class where occupied); the
    same over the union of occupied cells."""
    def states(m) -> dict[int, int]:
        c = m.cells()
        occ = m.is_occupied(c.logodds)
        state = np.where(occ, -1, -2).astype(np.int64)  # free -2, occupied: its top class
        labels, _ = m.class_at(keys_to_coords(unpack_keys(c.packed[occ]), m.resolution))
        state[occ] = labels
        return dict(zip(c.packed.tolist(), state.tolist(), strict=True))

    sa, sb = states(a), states(b)
    union = set(sa) | set(sb)
    same = sum(sa.get(k) == sb.get(k) for k in union)
    occ = {k for k in union if sa.get(k, -2) != -2 or sb.get(k, -2) != -2}
    same_occ = sum(sa.get(k) == sb.get(k) for k in occ)
    return same / max(len(union), 1), same_occ / max(len(occ), 1)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer frames and starts")
    ap.add_argument("--starts", type=int, default=None)
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--voxel-surface", action="store_true", help="ICP against the OctoMap's voxel centres (as "
                    "for a prior without a point map) instead of the point map's surface")
    ap.add_argument("--no-map-check", action="store_true", help="only the alignments (no continued run)")
    args = ap.parse_args()
    starts = args.starts if args.starts is not None else (4 if args.quick else 20)
    prior_frames, frames = (40, 16) if args.quick else (80, 30)
    intr = DEFAULT_INTRINSICS.scaled(0.5)
    scene = generate_scene(0, "office", "small")
    res = args.resolution
    out: dict = {"bench": "continue", "scene": "office-small-seed0", "resolution": res, "prior_frames": prior_frames,
                 "recording_frames": frames, "image": f"{intr.width}x{intr.height}"}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        poses_a = make_trajectory(scene, "loop", 600, seed=0)[:: 600 // prior_frames]  # once around the room
        out["prior_frames"] = len(poses_a)
        a = Recording(scene, poses_a, seed=0, intrinsics=intr, name="prior")
        t = time.perf_counter()
        run_config(config(tmp / "prior", "prior", res, (MapKind.OCTOMAP, MapKind.POINTS)), dataset=a)
        out["prior_s"] = round(time.perf_counter() - t, 1)
        octo = load_map(tmp / "prior" / "map.semmap")
        prior = prior_from_octomap(octo)
        surface = None if args.voxel_surface else load_map(tmp / "prior" / "points.semmap").cloud().centers
        out["icp_surface"] = "voxel centres" if args.voxel_surface else "point map"
        errors = []
        for seed in range(1, starts + 1):
            rec, T0 = recording(scene, seed, frames, 3, intr)
            t = time.perf_counter()
            try:
                al = align_recording(prior, ((f, f.T_world_cam) for f in rec), surface=surface, seed=seed,
                                     segment=_labels(rec.label_set))
                dt, dr = pose_change(T0, al.T_prior_seq)
                ft, fr = pose_change(T0, al.T_filter)
                errors.append({"seed": seed, "pos_err_m": round(dt, 4), "rot_err_deg": round(dr, 3),
                               "filter_pos_err_m": round(ft, 4), "filter_rot_err_deg": round(fr, 3),
                               "frames": al.frames_localized, "s": round(time.perf_counter() - t, 1)})
            except Exception as exc:  # (a failed start counts as not aligned)
                errors.append({"seed": seed, "failed": str(exc)})
            print(json.dumps(errors[-1]), file=sys.stderr)
        ok = [e for e in errors if "pos_err_m" in e and e["pos_err_m"] <= POS_TOL_M and e["rot_err_deg"] <= ROT_TOL_DEG]
        out.update({"starts": starts, "aligned_within_2cm_1deg": round(len(ok) / max(starts, 1), 3),
                    "errors": errors})
        if args.no_map_check:
            print(json.dumps(out))
            return
        # the continued map against both recordings mapped in one run
        rec, T0 = recording(scene, 1, frames, 3, intr, first_index=len(poses_a))
        t = time.perf_counter()
        cont = run_config(config(tmp / "cont", "rec1", res, (MapKind.OCTOMAP,)), dataset=rec,
                          continue_from=tmp / "prior")
        out["continue_s"] = round(time.perf_counter() - t, 1)
        out["continued_report"] = {k: cont.report["continued"][k] for k in (
            "converged_after_frames", "frames_localized", "particle_spread_m", "icp_correction_m", "translation_m",
            "rotation_deg")}
        out["continued_pos_err_m"], out["continued_rot_err_deg"] = (
            round(v, 4) for v in pose_change(T0, np.array(cont.report["continued"]["T_prior_seq"])))
        gt_b, _ = recording(scene, 1, frames, 3, intr, first_index=len(poses_a), relative=False)
        a = Recording(scene, poses_a, seed=0, intrinsics=intr, name="prior")
        both = run_config(config(tmp / "both", "both", res, (MapKind.OCTOMAP,)), dataset=Both(a, gt_b))
        cells, occupied = cell_agreement(cont.octomap, both.octomap)
        out.update({"cells_agree": round(cells, 4), "occupied_agree": round(occupied, 4)})
    print(json.dumps(out))


def _labels(label_set):
    return lambda f: semantics_for(f, SemanticSource.LABELS, label_set=label_set, label_confidence=0.9, k=3)


if __name__ == "__main__":
    main()
