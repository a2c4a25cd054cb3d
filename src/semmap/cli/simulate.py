"""``semmap simulate``: a procedural indoor scene rendered to a labelled RGB-D sequence."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from semmap.cli.options import MemoryBudget, budget, parse_size
from semmap.cli.terminal import ProgressCallback, interruptible, setup_logging, stderr_console
from semmap.errors import SemmapError


def simulate(
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder (TUM RGB-D layout + ground truth)")],
    scene_seed: Annotated[int, typer.Option(help="scene generator seed")] = 0,
    kind: Annotated[str, typer.Option(help="office | kitchen | living_room | bedroom")] = "office",
    size: Annotated[str, typer.Option(help="small | medium | large")] = "medium",
    trajectory: Annotated[str, typer.Option(help="desk | loop | orbit | walk")] = "loop",
    frames: Annotated[int, typer.Option(help="frames to render (30 per second)")] = 300,
    noise: Annotated[bool, typer.Option("--noise/--no-noise", help="Kinect-like depth noise")] = True,
    image_size: Annotated[str | None, typer.Option(help="store frames reduced to WIDTHxHEIGHT (e.g. 160x120 "
                                                   "training data for semmap train); rendered at 640x480")] = None,
    symmetric: Annotated[bool, typer.Option("--symmetric", help="one room whose geometry maps onto itself under a "
                                            "180° turn, its halves told apart only by their classes")] = False,
    trajectory_seed: Annotated[int | None, typer.Option(help="seed of the camera path (default: the scene seed); "
                                                        "another seed gives another path through the same scene")
                               ] = None,
    format: Annotated[str | None, typer.Option("--format", help="tum (semmap's own; the default) | scannet (a .sens "
                                               "scan, NYU-40 labels) | replica (NICE-SLAM layout, Semantic-NeRF "
                                               "labels)")] = None,
    changes: Annotated[int, typer.Option(help="the same scene a while later: N objects moved, removed or added "
                                              "(in turn); changes.json records them (for semmap diff)")] = 0,
    changes_seed: Annotated[int, typer.Option(help="seed of which objects change and where")] = 1,
    people: Annotated[int, typer.Option(help="people walking to and fro through the scene (labelled person; not "
                                             "in the 3D ground truth: semmap run keeps them out of the map)")] = 0,
    realism: Annotated[str, typer.Option(help="how real the sensor looks: clean (exact geometry, light depth noise; "
                                         "the default) | kinect (a Kinect v1 calibrated on 7-Scenes: depth, colour "
                                         "camera, hand-held motion) | hard (the same on a worse day); scene.json "
                                         "records it")] = "clean",
    memory_budget: MemoryBudget = None,
) -> None:
    """Render a procedural indoor scene to a TUM RGB-D folder with labels, instances, objects and scene.json."""
    setup_logging(False)
    budget(memory_budget)
    from semmap.sim.export import LAYOUTS, check_sequence_out, simulate_sequence

    stored = parse_size(image_size)
    if isinstance(stored, int):
        raise SemmapError(f"--image-size must be WIDTHxHEIGHT, got {image_size!r}")
    check_sequence_out(out)  # (before the progress bar: a refusal is one line)
    with interruptible(), ProgressCallback("rendering", frames) as callback:
        root = simulate_sequence(out, scene_seed=scene_seed, kind=kind, size=size, trajectory=trajectory,
                                 frames=frames, noise=noise, progress=callback, image_size=stored, symmetric=symmetric,
                                 trajectory_seed=trajectory_seed, layout=format or LAYOUTS[0],
                                 changes=changes, changes_seed=changes_seed, people=people, realism=realism)
    stderr_console().print(f"wrote {frames} frames to {root} (map it with: semmap run {root} --out OUT)")
