"""``semmap view`` of the files semmap writes beside its maps: the semantic mesh, the ESDF, the scene graph, the
navigation grid and costmap, a diff, objects.json and trajectories, each logged to rerun as what it is (a mesh,
coloured points, boxes and edges, an image, a path). Map files themselves are :func:`rerun_log.view_map`'s."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.types import EMPTY_LABEL

#: An ESDF shows at most this many voxels (every n-th beyond it), nearest the obstacles first.
MAX_ESDF_POINTS = 1_000_000
#: ESDF voxels farther than this from an obstacle are left out (they hide the structure).
ESDF_SHOWN_DISTANCE_M = 1.0
#: Suffixes and names :func:`is_product_file` takes.
PRODUCT_SUFFIXES = (".yaml", ".pgm", ".png", ".npy", ".npz", ".json", ".txt")


def is_product_file(path: Path) -> bool:
    """Whether ``view`` shows ``path`` here (a product, not a map file), by its suffix or its PLY header."""
    from semmap.io.mesh_ply import is_mesh_ply

    return path.suffix in PRODUCT_SUFFIXES or (path.suffix == ".ply" and is_mesh_ply(path))


def shown(path: Path) -> str:
    """What :func:`log_product`'s count counts, for the command's line."""
    nouns = {".ply": "mesh vertices", ".npz": "ESDF voxels", ".txt": "poses", "scene_graph.json": "scene graph nodes",
             "graph.json": "scene graph nodes", "diff.json": "changed voxels", "mesh.json": "mesh vertices",
             "esdf.json": "ESDF voxels", "objects.json": "objects"}
    from semmap.io.product_files import yaml_of_image

    if path.suffix in (".pgm", ".png") and yaml_of_image(path) is None:
        return "pixels"
    return nouns.get(path.name) or nouns.get(path.suffix) or "grid cells"


def log_product(rec, path: Path) -> int:
    """Log the product file ``path`` under ``world``; returns how many elements it drew (vertices, voxels, cells,
    nodes or poses)."""
    from semmap.io.product_files import yaml_of_image

    path = Path(path)
    if path.suffix == ".ply":
        return _mesh(rec, path)
    if path.suffix in (".pgm", ".png") and yaml_of_image(path) is None:  # a picture: preview, slice, plots
        import rerun as rr

        from semmap.io.product_files import read_image

        pixels = read_image(path)
        rec.log("image", rr.Image(pixels[..., [2, 1, 0, 3][: pixels.shape[2]]] if pixels.ndim == 3 else pixels))
        return int(pixels.shape[0] * pixels.shape[1])
    if path.suffix in (".yaml", ".pgm", ".png", ".npy"):
        return _grid(rec, path)
    if path.suffix == ".npz":
        return _esdf(rec, path)
    if path.suffix == ".json":
        return _json(rec, path)
    return _trajectory(rec, path)


def _mesh(rec, path: Path) -> int:
    import rerun as rr

    from semmap.io.mesh_ply import read_mesh_ply
    from semmap.viz.rerun_log import log_classes

    mesh = read_mesh_ply(path)
    colors = mesh.colors.copy()
    if mesh.label_set is not None:
        log_classes(rec, mesh.label_set)
        ok = (mesh.labels != EMPTY_LABEL) & (mesh.labels < len(mesh.label_set)) & (mesh.labels != 0)
        colors[ok] = mesh.label_set.colors[mesh.labels[ok]]
    rec.log("world/mesh", rr.Mesh3D(vertex_positions=mesh.vertices, triangle_indices=mesh.faces,
                                    vertex_colors=colors))
    return len(mesh)


def _grid(rec, path: Path) -> int:
    """A map_server grid or costmap as an image (row 0 at the top, as map_server draws it) and as cells on the
    floor plane in 3D (occupied dark, free light, costs in between; unknown left out)."""
    import rerun as rr

    from semmap.io.product_files import read_costmap_npy, read_map_server

    g = read_costmap_npy(path) if path.suffix == ".npy" else read_map_server(path)
    cells = g.cells.astype(np.int16)
    shade = np.where(cells < 0, 205, 255 - np.rint(2.55 * np.clip(cells, 0, 100))).astype(np.uint8)
    rec.log("grid", rr.Image(np.ascontiguousarray(shade.T[::-1])))
    ij = np.argwhere(cells >= 0)
    centers = np.column_stack([g.origin + (ij + 0.5) * g.resolution, np.zeros(len(ij))]).astype(np.float32)
    grey = shade[ij[:, 0], ij[:, 1]]
    half = 0.5 * g.resolution
    rec.log("world/grid", rr.Boxes3D(centers=centers, half_sizes=[half, half, 0.005],
                                     colors=np.repeat(grey[:, None], 3, axis=1), fill_mode="solid"))
    return int(cells.size)


def _esdf(rec, path: Path) -> int:
    """The observed voxels near obstacles as points coloured by signed distance (red inside, blue far)."""
    import rerun as rr

    from semmap.io.product_files import read_esdf_npz

    e = read_esdf_npz(path)
    d, res = e["distance"], float(e["resolution"])
    keep = e["observed"] & np.isfinite(d) & (d <= ESDF_SHOWN_DISTANCE_M)
    ijk = np.argwhere(keep)
    values = d[keep]
    if len(ijk) > MAX_ESDF_POINTS:
        order = np.argsort(np.abs(values), kind="stable")[:MAX_ESDF_POINTS]
        ijk, values = ijk[order], values[order]
    t = np.clip(values / ESDF_SHOWN_DISTANCE_M, -1.0, 1.0)
    colors = np.column_stack([np.where(t < 0, 220, 255 * (1 - t)), 255 * (1 - np.abs(t)),
                              np.where(t < 0, 255 * (1 + t), 220)]).astype(np.uint8)
    rec.log("world/esdf", rr.Points3D(positions=(e["origin"] + ijk * res).astype(np.float32), colors=colors,
                                      radii=0.35 * res))
    return len(ijk)


def _json(rec, path: Path) -> int:
    from semmap.io.product_files import read_json_limited

    if path.name == "scene_graph.json":
        return _scene_graph(rec, path)
    beside = {"grid.json": "map.yaml", "esdf.json": "esdf.npz", "graph.json": "scene_graph.json",
              "mesh.json": "mesh.ply", "diff.json": "diff.ply"}.get(path.name)
    if beside is not None:  # a product's summary: show the product it sums up
        if not (path.parent / beside).is_file():
            raise FormatError(f"{path}: {beside} is not beside it")
        if beside == "diff.ply":
            from semmap.viz.rerun_log import log_cloud, map_file_cloud

            cloud, label_set = map_file_cloud(path.parent / beside)
            log_cloud(rec, "world/diff", cloud, label_set)
            return len(cloud)
        return log_product(rec, path.parent / beside)
    data = read_json_limited(path, "JSON file")
    if isinstance(data, dict) and data.get("format") == "semmap-objects":
        return _objects(rec, data.get("objects", []))
    raise FormatError(f"{path}: not a JSON file semmap view shows (scene_graph.json, objects.json, or the summary "
                      f"of a grid, ESDF, scene graph, mesh or diff)")


def _boxes(rec, entity: str, centers: list, sizes: list, labels: list[str], colors) -> None:
    import rerun as rr

    if centers:
        rec.log(entity, rr.Boxes3D(centers=np.asarray(centers, np.float32),
                                   half_sizes=np.asarray(sizes, np.float32) / 2, labels=labels, colors=colors))


def _scene_graph(rec, path: Path) -> int:
    """Objects and rooms as boxes with their names, relations as lines between their centres."""
    import rerun as rr

    from semmap.io.product_files import read_scene_graph

    nodes, edges = read_scene_graph(path)
    for layer, colour in (("object", (240, 170, 30)), ("room", (90, 160, 240))):
        chosen = [n for n in nodes if n.layer == layer]
        _boxes(rec, f"world/{layer}s", [n.center for n in chosen], [np.maximum(n.size, 0.01) for n in chosen],
               [n.name for n in chosen], [colour] * len(chosen))
    for kind, colour in (("in", (90, 160, 240)), ("on", (230, 60, 60)), ("near", (160, 160, 160))):
        strips = [np.stack([nodes[a].center, nodes[b].center]) for k, a, b in edges if k == kind]
        if strips:
            rec.log(f"world/relations/{kind}", rr.LineStrips3D(strips, colors=[colour]))
    return len(nodes)


def _objects(rec, objects: list) -> int:
    """objects.json: each object's box, labelled ``id class``."""
    try:
        boxes = [(o["box"]["center"], o["box"]["extent"], f"{o['id']} {o['class']}") for o in objects]
    except (KeyError, TypeError):
        raise FormatError("objects.json: an object without id, class and box") from None
    _boxes(rec, "world/objects", [b[0] for b in boxes], [b[1] for b in boxes], [b[2] for b in boxes],
           [(240, 170, 30)] * len(boxes))
    return len(boxes)


def _trajectory(rec, path: Path) -> int:
    import rerun as rr

    from semmap.files.safe import read_text_limited
    from semmap.io.trajectory import read_trajectory

    rows = [line.split() for line in read_text_limited(path, what="text file").splitlines() if line.strip()
            and not line.lstrip().startswith("#")]
    if len(rows) == 4 and all(len(r) == 4 for r in rows):
        raise FormatError(f"{path}: a 4x4 transform has nothing to draw; view the merged map beside it (map.semmap)")
    traj = read_trajectory(path)
    rec.log("world/trajectory", rr.LineStrips3D([traj.poses[:, :3, 3].astype(np.float32)], colors=[(255, 140, 0)]))
    return len(traj.timestamps)
