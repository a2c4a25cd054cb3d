"""Products of finished maps: ``semmap diff`` (what changed), ``merge`` (two maps of one place) and the ``export``
group (navigation grid and costmap, scene graph, ESDF, semantic mesh)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from semmap.cli.options import Json
from semmap.cli.terminal import setup_logging, summary_out


def diff(
    before: Annotated[Path, typer.Argument(help="the earlier map: .semmap or a run folder")],
    after: Annotated[Path, typer.Argument(help="the later map of the same place, in the same frame")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder: diff.json, diff.ply, diff.png")],
    match_radius: Annotated[float, typer.Option(help="objects of one class closer than this are the same object "
                                                "(m); farther ones pair as moved by space, size and colour")] = 1.0,
    move_threshold: Annotated[float, typer.Option(help="a matched object farther than this moved (m)")] = 0.2,
) -> None:
    """What changed between two maps of one place: voxels that appeared, disappeared or changed class (only where
    both maps saw the space) and, for run folders with objects.json, objects that appeared, disappeared or moved."""
    setup_logging(False)
    from semmap.products.export import export_diff

    s = export_diff(before, after, out, match_radius=match_radius, move_threshold=move_threshold)
    v, o = s["voxels"], s["objects"]
    objects = "" if o is None else (f"; objects: {o['appeared']} appeared, {o['disappeared']} disappeared, "
                                    f"{o['moved']} moved, {o.get('unknown', 0)} unknown")
    typer.echo(f"{out}: voxels {v['appeared']:,} appeared, {v['disappeared']:,} disappeared, {v['relabelled']:,} "
               f"changed class ({v['observed_by_both']:,} seen by both){objects}")


def merge(
    map_a: Annotated[Path, typer.Argument(metavar="A", help="a map: .semmap (OctoMap, voxel grid or point map) or a "
                                          "run folder; the merged map is in its frame")],
    map_b: Annotated[Path, typer.Argument(metavar="B", help="a map of the same place, kind, resolution and classes")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output: a folder (the map's files, transform.txt, "
                                      "merge.json) or a .semmap file; never A or B")],
    transform: Annotated[Path | None, typer.Option(help="text file of the 4x4 transform taking B's coordinates into "
                                                   "A's frame (default: estimated from the occupied voxels)")] = None,
    min_overlap: Annotated[float, typer.Option(help="refuse an alignment (estimated or given) unless this share of "
                                               "the smaller map's occupied voxels meets the other map (0: merge "
                                               "maps that share no space)")] = 0.3,
    as_json: Json = False,
) -> None:
    """Merge two maps of one place: B aligned to A (a given transform, or FPFH + RANSAC then ICP, checked for a
    sane overlap), evidence combined by the maps' own occupancy update and fusion rule."""
    setup_logging(False)
    from semmap.products.merge import merge_map_files

    s = merge_map_files(map_a, map_b, out, transform=transform, min_overlap=min_overlap)
    al, occ = s["alignment"], s["occupied"]
    rows = [("alignment", f"{al['source']}" + (f" (from the {al['start']})" if al["start"] else "")),
            ("overlap", f"{100 * al['overlap']:.1f} % of the smaller map's occupied voxels, RMSE "
                        + ("-" if al["rmse_m"] is None else f"{100 * al['rmse_m']:.2f} cm")),
            ("occupied voxels", f"A {occ['a']:,}, B {occ['b']:,}, merged {occ['merged']:,}"),
            ("written", str(out))]
    summary_out(s, as_json, f"semmap merge: {s['kind']} at {s['resolution']} m", rows)


export_app = typer.Typer(no_args_is_help=True, help="Robot products from a finished map: a 2D navigation grid "
                         "and semantic costmap (ROS map_server), a Euclidean signed distance field, the semantic "
                         "mesh of a TSDF.")

_ExportMap = Annotated[Path, typer.Argument(help="a map: .semmap (any kind) or a run folder")]
_ExportOut = Annotated[Path, typer.Option("--out", "-o", help="output folder (written whole or not at all)")]
_Region = Annotated[str | None, typer.Option(help="bounded region 'xmin ymin zmin xmax ymax zmax' (m; default: "
                                                  "everything the map knows)")]


def _region(text: str | None) -> tuple[float, ...] | None:
    from semmap.limits import check_option

    return check_option("--region", text)


def _class_costs(items: list[str]) -> dict[str, int]:
    from semmap.errors import ConfigError

    out = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            out[name.strip()] = int(value)
        except ValueError:
            raise ConfigError(f"--cost {item!r}: write CLASS=COST with COST a whole number 0..100") from None
    return out


@export_app.command("grid")
def export_grid_command(
    map_path: _ExportMap,
    out: _ExportOut,
    z_min: Annotated[float, typer.Option(help="band above the floor that blocks the robot: from (m)")] = 0.1,
    z_max: Annotated[float, typer.Option(help="... to (m): the robot's height")] = 1.5,
    floor: Annotated[float | None, typer.Option(help="floor height (m; default: detected from floor-class voxels, "
                                                     "else the lowest dense layer)")] = None,
    no_go: Annotated[str, typer.Option(help="classes never to enter, comma-separated (e.g. person,stairs)")] = "",
    cost: Annotated[list[str] | None, typer.Option(help="CLASS=COST (0..100) for the costmap, repeatable (e.g. "
                                                        "door=50)")] = None,
    inflation: Annotated[float, typer.Option(help="robot radius (m): costmap cells this close to an obstacle "
                                                  "get cost 99")] = 0.0,
    region: _Region = None,
) -> None:
    """A 2D occupancy grid (map.pgm + map.yaml, ROS map_server trinary) and a semantic costmap (costmap.png +
    costmap.yaml in scale mode, costmap.npy exact) from a map; unknown space stays unknown."""
    setup_logging(False)
    from semmap.products.export import export_grid
    from semmap.products.navgrid import GridOptions

    options = GridOptions(z_min=z_min, z_max=z_max, floor=floor,
                          no_go=tuple(n.strip() for n in no_go.split(",") if n.strip()),
                          costs=_class_costs(cost or []), inflation=inflation)
    s = export_grid(map_path, out, options, _region(region))
    c = s["cells"]
    typer.echo(f"{out}: {s['size_cells'][0]}x{s['size_cells'][1]} cells at {s['resolution']} m, floor "
               f"{s['floor_z']:.2f} m; occupied {c['occupied']:,}, free {c['free']:,}, unknown {c['unknown']:,}")


@export_app.command("scene-graph")
def export_scene_graph_command(
    run: Annotated[Path, typer.Argument(help="a run folder with objects.json (semmap run ... --instances ...)")],
    out: _ExportOut,
    sequence: Annotated[Path | None, typer.Option(help="the run's sequence (default: the one its config.json "
                                                       "names); a simulated one gives the true rooms")] = None,
    near: Annotated[float, typer.Option(help="objects of one room closer than this are 'near' (m)")] = 1.0,
    door_width: Annotated[float, typer.Option(help="room segmentation of real maps: doors narrower than this "
                                                   "separate rooms (m)")] = 1.0,
) -> None:
    """A scene graph (scene_graph.json, spark-dsg / Hydra): objects, rooms (the simulator's layout, or a room
    segmentation of the map's navigation grid) and relations (in room, on, near)."""
    setup_logging(False)
    from semmap.products.export import export_scene_graph

    s = export_scene_graph(run, out, sequence=sequence, near=near, door_width=door_width)
    c = s["counts"]
    typer.echo(f"{out}: {c['objects']} objects, {c['rooms']} rooms (from the {s['rooms_from']}); relations: "
               f"{c['in']} in, {c['on']} on, {c['near']} near")


@export_app.command("esdf")
def export_esdf_command(
    map_path: _ExportMap,
    out: _ExportOut,
    region: _Region = None,
    slice_z: Annotated[float | None, typer.Option(help="height of the slice picture (m; default: the middle)")] = None,
) -> None:
    """A Euclidean signed distance field at the map's resolution (esdf.npz: distance, observed, origin, resolution;
    positive outside obstacles, negative inside) and a slice picture."""
    setup_logging(False)
    from semmap.products.export import export_esdf

    s = export_esdf(map_path, out, _region(region), slice_z)
    n = s["size_voxels"]
    largest = ("none: the region holds no obstacle or no free voxel (every distance unbounded)"
               if s["max_distance_m"] is None else f"{s['max_distance_m']} m")
    typer.echo(f"{out}: {n[0]}x{n[1]}x{n[2]} voxels at {s['resolution']} m in {s['ms']:.0f} ms; largest distance "
               f"{largest}")
@export_app.command("mesh")
def export_mesh_command(
    map_path: Annotated[Path, typer.Argument(help="a run folder of 'semmap run --maps ...,tsdf', or its tsdf.semmap")],
    out: _ExportOut,
    min_weight: Annotated[int, typer.Option(help="observations a TSDF voxel needs to count")] = 1,
) -> None:
    """The semantic mesh (mesh.ply: per-vertex colour, class, confidence and class probabilities) by marching cubes
    over the TSDF, classes from the run folder's semantic map (its OctoMap first), else the TSDF's own."""
    setup_logging(False)
    from semmap.products.export import export_mesh

    s = export_mesh(map_path, out, min_weight=min_weight)
    typer.echo(f"{out}: {s['vertices']:,} vertices, {s['faces']:,} triangles in {s['ms']:.0f} ms; classes from "
               f"{s['labels_from']}, {100 * s['classified_share']:.1f}% of vertices classified")
