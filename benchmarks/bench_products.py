"""Robot products against their peers in the same run: the navigation grid export, the exact ESDF against scipy's
Euclidean distance transform (time and error), the incremental ESDF update per frame against a full recompute, and
the semantic mesh (marching cubes over semmap's TSDF and per-vertex classes) against Open3D's VoxelBlockGrid mesh
extraction over the same frames, on the 7-Scenes map at 2 cm (../shared) and a simulated house at 5 cm.

    python benchmarks/bench_products.py [--quick] [--frames N] [--scene 7scenes|house|all]

``--frames 0`` maps every frame of the sequence (the full 7-Scenes map). A ``total`` row per scene sums the grid,
ESDF and mesh times: what exporting all three products of one map costs.

The maps are built as `semmap run --maps octomap,tsdf` builds them (ground-truth poses); the timings are of what
`semmap export grid|esdf|mesh` runs. The mesh row's error is the share of vertices (among those whose voxel, or
nearest occupied voxel within one voxel, is occupied in the OctoMap) whose class differs from that voxel's, read
with the OctoMap's own ``class_at`` and a KD-tree over its occupied voxels (not the mesh's lookup).
The last line is JSON:
``{"bench": "products", "results": [{"scene", "product", "ms", "bytes", "error", "peer", "peer_ms"}]}``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import tempfile
import time
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "7scenes-redkitchen"


def timed(fn, repeat: int = 3) -> tuple[float, object]:
    """Best of ``repeat`` wall times (ms) after one warm-up call, and the result."""
    out = fn()
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best * 1e3, out


def build_map(frames, resolution: float, label_set, snapshots: int):
    """The OctoMap and TSDF of ``frames``, the occupied keys after each of the last ``snapshots`` frames, and
    Open3D's VoxelBlockGrid of the same frames (same voxel and truncation)."""
    from semmap.maps.semantic_octomap import SemanticOctoMap
    from semmap.maps.tsdf import TsdfMap
    from semmap.pipeline import Mapper
    from semmap.types import TopKProbs

    m = SemanticOctoMap(resolution, label_set=label_set)
    tsdf = TsdfMap(resolution, label_set=label_set)
    mapper = Mapper([m, tsdf], min_depth=0.1, max_depth=4.0)
    frames = list(frames)
    keys = []
    peer = Open3dTsdf(resolution, tsdf.truncation)
    for i, f in enumerate(frames):
        sem = (TopKProbs.from_hard_labels(f.labels, 0.9, len(label_set))
               if label_set is not None and f.labels is not None else None)
        mapper.integrate(f, f.T_world_cam, sem)
        peer.integrate(f)
        if i >= len(frames) - snapshots - 1:
            keys.append(m.voxels().keys)
    return m, tsdf, peer, keys


class Open3dTsdf:
    """Open3D's CPU VoxelBlockGrid (tsdf, weight, colour) integrating the same depth and colour images."""

    def __init__(self, voxel: float, truncation_voxels: float):
        import open3d as o3d
        import open3d.core as o3c

        self.o3d, self.o3c, self.trunc = o3d, o3c, truncation_voxels
        self.vbg = o3d.t.geometry.VoxelBlockGrid(("tsdf", "weight", "color"), (o3c.float32,) * 3, ((1), (1), (3)),
                                                  voxel, 8, 20000, o3c.Device("CPU:0"))

    def integrate(self, f) -> None:
        o3d, o3c = self.o3d, self.o3c
        depth = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(f.depth, np.float32)))
        color = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(f.rgb, np.float32) / 255.0))
        K = o3c.Tensor(f.intrinsics.K, o3c.float64)
        E = o3c.Tensor(np.linalg.inv(f.T_world_cam), o3c.float64)
        blocks = self.vbg.compute_unique_block_coordinates(depth, K, E, 1.0, 4.0, self.trunc)
        self.vbg.integrate(blocks, depth, color, K, K, E, 1.0, 4.0, self.trunc)

    def mesh(self):
        return self.vbg.extract_triangle_mesh(1.0)


def mesh_row(name: str, m, tsdf, peer) -> dict:
    """The semantic mesh (marching cubes + labels from the OctoMap) against Open3D's mesh extraction; its error is
    the share of classed vertices whose class is not their voxel's (own voxel by ``class_at``, else the nearest
    occupied voxel within one voxel by a KD-tree)."""
    from scipy.spatial import cKDTree

    from semmap.io.mesh_ply import write_mesh_ply
    from semmap.maps.mesh import semantic_mesh
    from semmap.types import EMPTY_LABEL

    ms, mesh = timed(lambda: semantic_mesh(tsdf, m), repeat=2)
    mc_ms, _ = timed(tsdf.mesh, repeat=2)
    peer_ms, pm = timed(peer.mesh, repeat=2)
    with tempfile.TemporaryDirectory() as tmp:
        size = write_mesh_ply(Path(tmp) / "mesh.ply", mesh)
    v = mesh.vertices.astype(np.float64)
    truth, _ = m.class_at(v)
    cloud = m.cloud()
    todo = truth == EMPTY_LABEL
    if todo.any() and len(cloud):
        res = m.resolution
        d, j = cKDTree(cloud.centers).query(v[todo], k=27, distance_upper_bound=2 * res)
        near = np.full(todo.sum(), EMPTY_LABEL, np.uint16)
        for col in range(27):  # nearest occupied voxel among the 26 neighbours of the vertex's voxel
            ok = np.isfinite(d[:, col]) & (near == EMPTY_LABEL)
            ok[ok] &= np.all(np.abs(np.floor(cloud.centers[j[ok, col]] / res) - np.floor(v[todo][ok] / res)) <= 1,
                             axis=1)
            near[ok] = cloud.labels[j[ok, col]]
        truth[todo] = near
    judged = truth != EMPTY_LABEL
    agree = float((mesh.labels[judged] == truth[judged]).mean()) if judged.any() else 1.0
    return {"scene": name, "product": "mesh", "ms": round(ms, 1), "bytes": size, "error": round(1.0 - agree, 6),
            "peer": "open3d VoxelBlockGrid.extract_triangle_mesh", "peer_ms": round(peer_ms, 1),
            "marching_cubes_ms": round(mc_ms, 1), "vertices": len(mesh), "faces": len(mesh.faces),
            "peer_vertices": int(pm.vertex.positions.shape[0]), "classified_share": round(float(judged.mean()), 4),
            "class_agreement": round(agree, 6)}


def spread_then_consecutive(frames, total: int, n: int, last: int):
    """``n - last`` frames spread over the first part of a ``total``-frame sequence, then its ``last`` frames one
    after another (the per-frame update is timed on consecutive frames, as a robot's camera delivers them)."""
    step = max(1, (total - last) // max(n - last, 1))
    keep = set(range(0, total - last, step)) | set(range(total - last, total))
    return (f for f in frames if f.index in keep)


def scenes(args) -> list[tuple[str, float, object, object]]:
    """(name, resolution, frames, label set) of each scene the run can reach."""
    from semmap.datasets import open_dataset
    from semmap.datasets.simulated import SimulatedDataset
    from semmap.sim.scene import generate_scene
    from semmap.sim.trajectory import make_trajectory
    from semmap.types import CameraIntrinsics

    out = []
    n = 40 if args.quick else args.frames
    if args.scene in ("7scenes", "all") and SHARED.is_dir():
        ds = open_dataset(SHARED)
        out.append(("7scenes-redkitchen", 0.02,
                    spread_then_consecutive(ds, len(ds), n or len(ds), args.snapshots + 1), None))
    elif args.scene in ("7scenes", "all"):
        print(f"skipping 7-Scenes: {SHARED} not found")
    if args.scene not in ("house", "all"):
        return out
    n = n or 200
    camera = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
    scene = generate_scene(0, "living_room", "large")
    walk = make_trajectory(scene, "walk", 10 * n, seed=0)  # 30 fps
    ds = SimulatedDataset(scene, walk, intrinsics=camera, name="sim-house")
    out.append(("sim-house", 0.05, spread_then_consecutive(ds, len(walk), n, args.snapshots + 1), ds.label_set))
    return out


def measure_scene(name: str, resolution: float, frames, label_set, snapshots: int) -> list[dict]:
    from scipy import ndimage

    from semmap.products._edt_kernels import squared_edt
    from semmap.products.esdf import IncrementalEsdf, esdf_of
    from semmap.products.map_server import write_costmap, write_map
    from semmap.products.navgrid import navigation_grid
    from semmap.products.occupancy import OCCUPIED, occupancy_volume

    frames = list(frames)
    m, tsdf, peer, history = build_map(frames, resolution, label_set, snapshots)
    rows = [mesh_row(name, m, tsdf, peer)]
    grid_ms, grid = timed(lambda: navigation_grid(occupancy_volume(m)))
    with tempfile.TemporaryDirectory() as tmp:
        files = write_map(Path(tmp), "map", grid.occupancy, grid.resolution, grid.origin)
        files += write_costmap(Path(tmp), "costmap", grid.cost, grid.resolution, grid.origin)
        size = sum(f.stat().st_size for f in files)
    rows.append({"scene": name, "product": "grid", "ms": round(grid_ms, 1), "bytes": size, "error": None,
                 "peer": None, "peer_ms": None})
    vol = occupancy_volume(m)
    occ = vol.state == OCCUPIED
    ms, e = timed(lambda: esdf_of(vol))

    def scipy_signed():
        return np.where(occ, -ndimage.distance_transform_edt(occ), ndimage.distance_transform_edt(~occ)) * resolution

    peer_ms, ref = timed(scipy_signed, repeat=1)
    rows.append({"scene": name, "product": "esdf", "ms": round(ms, 1), "bytes": int(e.distance.nbytes),
                 "error": float(np.abs(e.distance - ref).max()), "peer": "scipy.ndimage.distance_transform_edt",
                 "peer_ms": round(peer_ms, 1), "voxels": int(occ.size)})
    rows.append(incremental_row(name, vol, history, squared_edt, IncrementalEsdf))
    total = sum(r["ms"] for r in rows if r["product"] in ("mesh", "grid", "esdf"))
    rows.append({"scene": name, "product": "total grid+esdf+mesh", "ms": round(total, 1),
                 "bytes": sum(r["bytes"] for r in rows if r["product"] in ("mesh", "grid", "esdf")), "error": None,
                 "peer": None, "peer_ms": None, "frames": len(frames), "voxels": int(occ.size)})
    return rows


def incremental_row(name: str, vol, history: list[np.ndarray], squared_edt, incremental_cls) -> dict:
    """Per-frame update from the voxels that flipped against the full unsigned transform of the same frame (mean
    over the frames of each one's best of 3 passes)."""
    lo = np.rint((vol.origin / vol.resolution) - 0.5).astype(np.int64) + 32768
    masks = []
    for keys in history:
        mask = np.zeros(vol.shape, bool)
        idx = keys - lo
        ok = np.all((idx >= 0) & (idx < np.array(vol.shape)), axis=1)
        mask[tuple(idx[ok].T)] = True
        masks.append(mask)
    max_d = 2.0
    steps = len(masks) - 1
    times, full, errors = np.full(steps, np.inf), np.full(steps, np.inf), []
    flips = int(np.mean([(a != b).sum() for a, b in itertools.pairwise(masks)]))
    for repeat in range(3):  # best of 3 per frame, as timed() does for the other rows; each pass starts afresh
        inc = incremental_cls(vol.shape, vol.resolution, vol.origin, max_distance=max_d)
        inc.update(masks[0])
        for i, mask in enumerate(masks[1:]):
            t = time.perf_counter()
            inc.update(mask)
            times[i] = min(times[i], time.perf_counter() - t)
            t = time.perf_counter()
            ref = np.sqrt(squared_edt(mask)) * vol.resolution
            full[i] = min(full[i], time.perf_counter() - t)
            if repeat == 0:
                ref[ref > max_d] = np.inf
                got = inc.distance()
                fin = np.isfinite(ref) & np.isfinite(got)
                errors.append(float(np.abs(got[fin] - ref[fin]).max()) if fin.any() else 0.0)
    return {"scene": name, "product": "esdf-incremental-per-frame", "ms": round(1e3 * float(np.mean(times)), 2),
            "bytes": None, "error": max(errors), "peer": "full exact transform of the frame",
            "peer_ms": round(1e3 * float(np.mean(full)), 2), "frames": steps, "flipped_per_frame": flips}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="40 frames per scene")
    ap.add_argument("--frames", type=int, default=200, help="frames per scene (0: every frame of 7-Scenes)")
    ap.add_argument("--scene", choices=("7scenes", "house", "all"), default="all", help="which scenes to map")
    ap.add_argument("--snapshots", type=int, default=10, help="frames whose incremental update is timed")
    args = ap.parse_args()
    results = []
    for name, res, frames, labels in scenes(args):
        for row in measure_scene(name, res, frames, labels, args.snapshots):
            ratio = "" if not row["peer_ms"] else f"  x{row['peer_ms'] / max(row['ms'], 1e-9):.1f} vs peer"
            print(f"{row['scene']:20s} {row['product']:28s} {row['ms']:9.1f} ms  error {row['error']}{ratio}")
            results.append(row)
    print(json.dumps({"bench": "products", "results": results}))


if __name__ == "__main__":
    main()
