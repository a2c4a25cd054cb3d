"""One registry per family is the only list of its names: no string literal in ``src/`` spells a registered name
outside the family's own modules, and the CLI's help, choices and defaults come from the registries and the run
configuration."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import typer.main
from typer.testing import CliRunner

from semmap.cli import app
from semmap.config import (
    CrfConfig,
    InputConfig,
    MappingConfig,
    ObjectsConfig,
    OutputConfig,
    PosesConfig,
    RunConfig,
    SemanticsConfig,
)
from semmap.datasets import AUTO, FORMATS, DatasetFormat, detect_format
from semmap.errors import ConfigError, SemmapError
from semmap.fusion.rules import FusionRule
from semmap.maps.registry import MAPS, MapKind
from semmap.perception.instances.registry import INSTANCE_SOURCES, InstanceSourceName
from semmap.perception.networks.registry import MODELS
from semmap.perception.registry import SEGMENTERS, TRAINED_NETWORKS, SegmenterName
from semmap.poses.track import GROUND_TRUTH, OBJECT_METHODS, POSE_SOURCES, TRACKERS, PoseSource
from semmap.registry import Registry

SRC = Path(__file__).resolve().parents[1] / "src" / "semmap"

#: family -> (its names, the modules that may spell them: the registry and the entries' own files).
FAMILIES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "pose source": (POSE_SOURCES, ("poses/track.py",)),
    "segmenter": ((*SEGMENTERS, *MODELS), ("perception/registry.py", "perception/networks/registry.py")),
    "instance source": (tuple(INSTANCE_SOURCES), ("perception/instances/registry.py",)),
    "map": (tuple(MAPS), ("maps/registry.py",)),
    "dataset format": (tuple(FORMATS), ("datasets/tum.py", "datasets/sevenscenes.py", "datasets/rosbag.py",
                                         "datasets/scannet.py", "datasets/replica.py", "datasets/stills.py")),
    "fusion rule": (tuple(r.value for r in FusionRule), ("fusion/rules.py", "fusion/registry.py")),
}
#: (file, literal) pairs where the same word means something else, each with the reason.
ALLOWED: dict[tuple[str, str], str] = {
    ("eval/run_report.py", "max"): "the largest latency of an online run (a statistic, not the fusion rule)",
    ("localization/outputs.py", "max"): "the largest localization error (a statistic)",
    ("localization/run.py", "max"): "the largest localization error (a statistic)",
    ("sim/scene.py", "max"): "a bounding box's upper corner",
    ("config.py", "oracle"): "SemanticSource.ORACLE: a value of --semantics (where class probabilities come from)",
    ("perception/network.py", "onnx"): "--backend onnx: the ONNX Runtime backend of semmap's networks (and its cache "
                                       "folder), not the segmenter onnx:MODEL",
    ("runner.py", "onnx"): "--backend onnx for the demo's network (the runtime, not the segmenter onnx:MODEL)",
    ("localization/sequence.py", "odometry"): "--motion odometry: a localization motion source (MOTION_SOURCES)",
    ("cli/localize.py", "odometry"): "the default of localize --motion (a localization motion source)",
    ("eval/report_md.py", "points"): "the 'points' count of a report entry",
    ("io/map_info.py", "points"): "the 'points' count of a .ply file's description",
    ("io/objects.py", "points"): "the 'points' field of objects.json / objects.ply",
    ("object_stage.py", "points"): "the 'points' count of an object in the report",
    ("maps/point_map.py", "points"): "the 'points' count of the point map's description",
    ("products/scene_graph.py", "points"): "the 'points' field of objects.json, copied into the graph's metadata",
    ("products/changes.py", "points"): "the 'points' count of an objects.json record (which part of an object leads)",
    ("products/export.py", "points"): "the 'points' array of objects.ply (each object's place for semmap diff)",
    **{("sim/export.py", layout): "a layout semmap simulate writes (sim lies below datasets and its registry; "
       "tests/test_benchmark_readers.py reads each back with its reader)" for layout in ("tum", "scannet", "replica")},
}


def _docstrings(tree: ast.AST) -> set[int]:
    """ids of the docstring constants of a module, its classes and functions (prose may name anything)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def _own_names(tree: ast.AST) -> set[int]:
    """ids of the constants in ``name = "..."`` of a class body: how a component names itself in reports."""
    out = set()
    for cls in (n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)):
        for stmt in cls.body:
            if (isinstance(stmt, ast.Assign) and [getattr(t, "id", None) for t in stmt.targets] == ["name"]
                    and isinstance(stmt.value, ast.Constant)):
                out.add(id(stmt.value))
    return out


def _strings(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, text) of the string constants of ``tree`` that are not docstrings or a component's own name."""
    skip = _docstrings(tree) | _own_names(tree)
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in skip]


def _literals() -> list[tuple[str, int, str]]:
    """(file relative to src/semmap, line, text) of every such string constant in src/."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        found += [(rel, line, text) for line, text in _strings(ast.parse(path.read_text(), filename=str(path)))]
    return found


@pytest.mark.slow
def test_no_family_name_is_spelled_outside_its_registry() -> None:
    homes: dict[str, set[str]] = {}  # name -> files that may spell it (a word two families share has both homes)
    families: dict[str, list[str]] = {}
    for family, (names, files) in FAMILIES.items():
        for name in names:
            homes.setdefault(name, set()).update(files)
            families.setdefault(name, []).append(family)
    used_allowances = set()
    stray = []
    for rel, line, text in _literals():
        if text not in homes or rel in homes[text]:
            continue
        if (rel, text) in ALLOWED:
            used_allowances.add((rel, text))
            continue
        stray.append(f"src/semmap/{rel}:{line}: {' / '.join(families[text])} {text!r}")
    assert not stray, "names spelled out outside their registry (use the registry or its enum):\n" + "\n".join(stray)
    assert set(ALLOWED) == used_allowances, f"stale allowances: {sorted(set(ALLOWED) - used_allowances)}"


def test_the_scan_finds_a_stray_name() -> None:
    tree = ast.parse('"""slam in prose"""\nclass T:\n    name = "slam"\nx = {"slam": 1}\nif m == "odometry": pass\n')
    # the dict key and the comparison, not the docstring nor the class's own name
    assert _strings(tree) == [(4, "slam"), (5, "odometry")]


def test_registry_lookup_lists_the_choices_in_one_line() -> None:
    for registry in (TRACKERS, SEGMENTERS, INSTANCE_SOURCES, MAPS, MODELS):
        with pytest.raises(ConfigError) as info:
            registry["no-such-thing"]
        message = str(info.value)
        prefix = f"{registry.option}: " if registry.option else ""  # the option that takes the name, if one does
        assert "\n" not in message and message.startswith(f"{prefix}unknown {registry.family} 'no-such-thing'; "
                                                           "choose from ")
        assert all(name in message for name in registry)
    assert "no-such-thing" not in TRACKERS and [] not in TRACKERS


def test_registries_refuse_a_name_twice() -> None:
    entry = TRACKERS["slam"]
    with pytest.raises(ValueError, match="twice"):
        Registry("tracker", [entry, entry])


def test_entries_say_what_they_can_do() -> None:
    assert set(TRAINED_NETWORKS) == set(MODELS) == set(SEGMENTERS.where(trained=True))
    assert {n for n in SEGMENTERS if SEGMENTERS[n].uses_depth} == {n for n in MODELS if MODELS[n].uses_depth}
    assert SEGMENTERS.where(needs_weights=True) and INSTANCE_SOURCES.where(needs_weights=True)
    assert tuple(f"{n}-objects" for n in TRACKERS.where(objects=True)) == OBJECT_METHODS
    for name in MAPS:
        assert MAPS[name].default_fusion in MAPS[name].fusion_rules
    assert all(entry.help and "\n" not in entry.help for r in (TRACKERS, SEGMENTERS, INSTANCE_SOURCES, MAPS, FORMATS)
               for entry in r.values())


def test_enums_are_the_registries_names() -> None:
    assert [m.value for m in SegmenterName] == list(SEGMENTERS)
    assert [m.value for m in InstanceSourceName] == list(INSTANCE_SOURCES)
    assert [m.value for m in MapKind] == list(MAPS)
    assert [m.value for m in DatasetFormat] == [AUTO, *FORMATS]
    assert [m.value for m in PoseSource] == [GROUND_TRUTH, *TRACKERS, *OBJECT_METHODS] == list(POSE_SOURCES)


def test_config_fields_are_typed_with_the_families_enums(tmp_path: Path) -> None:
    c = RunConfig(input=InputConfig(dataset=tmp_path, format="tum"), output=OutputConfig(out=tmp_path),
                  mapping=MappingConfig(maps=("voxelgrid", "octomap")),
                  semantics=SemanticsConfig(segmenter="fcn", fusion="vote"),
                  poses=PosesConfig(source="slam-objects"), objects=ObjectsConfig(instances="components"))
    assert isinstance(c.input.format, DatasetFormat) and c.input.format == "tum"
    assert isinstance(c.semantics.segmenter, SegmenterName) and c.semantics.segmenter == "fcn"
    assert isinstance(c.objects.instances, InstanceSourceName)
    assert isinstance(c.poses.source, PoseSource) and c.mapping.maps == (MapKind.VOXELGRID, MapKind.OCTOMAP)
    assert RunConfig.model_validate_json(c.to_json()) == c  # config.json round trip
    assert '"source": "slam-objects"' in c.to_json()
    path = PosesConfig(source=str(tmp_path / "traj.txt")).source
    assert isinstance(path, Path) and path == tmp_path / "traj.txt"
    assert PosesConfig().source == GROUND_TRUTH


@pytest.mark.parametrize(("make", "message"), [
    (lambda: SemanticsConfig(segmenter="segnet"), "unknown segmenter 'segnet'; choose from oracle, "),
    (lambda: ObjectsConfig(instances="yolo"), "unknown instance source 'yolo'; choose from oracle, "),
    (lambda: InputConfig(dataset=".", format="kitti"), "unknown dataset format 'kitti'; choose from auto, "),
    (lambda: MappingConfig(maps=("octomap", "mesh")), "unknown map 'mesh'; choose from octomap, voxelgrid, points"),
])
def test_config_names_an_unknown_member_with_the_choices(make, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make()


def _options(command: str) -> dict:
    """name -> click option of a CLI command."""
    cmd = typer.main.get_command(app).commands[command]
    return {p.name: p for p in cmd.params}


def test_cli_help_lists_the_registries() -> None:
    run = _options("run")
    assert SEGMENTERS.choices() in run["segmenter"].help
    assert INSTANCE_SOURCES.choices() in run["instances"].help
    assert MAPS.choices() in run["maps"].help
    assert FORMATS.choices((AUTO,)) == run["format"].help
    assert TRACKERS.choices() in run["poses"].help and "X-objects" in run["poses"].help
    track = _options("track")
    assert track["method"].help == TRACKERS.choices() and track["method"].default == TRACKERS.names[0]
    assert _options("train")["model"].help == MODELS.choices()
    assert SEGMENTERS.choices() in _options("localize")["segmenter"].help
    assert _options("batch")["segmenter"].help == SEGMENTERS.choices()


def test_cli_defaults_are_the_configs() -> None:
    run = _options("run")
    expected = {
        "resolution": (MappingConfig, "resolution"), "min_depth": (MappingConfig, "min_depth"),
        "max_depth": (MappingConfig, "max_depth"), "max_range": (MappingConfig, "max_range"),
        "pixel_stride": (MappingConfig, "pixel_stride"), "point_resolution": (MappingConfig, "point_resolution"),
        "lam": (SemanticsConfig, "lam"), "top_k": (SemanticsConfig, "k"),
        "max_confidence": (SemanticsConfig, "max_confidence"), "label_confidence": (SemanticsConfig,
                                                                                    "label_confidence"),
        "segment_every": (SemanticsConfig, "segment_every"), "batch_size": (SemanticsConfig, "batch_size"),
        "backend": (SemanticsConfig, "backend"), "crf_every": (CrfConfig, "every"),
        "instance_errors": (ObjectsConfig, "errors"), "rerun_map_every": (OutputConfig, "rerun_map_every"),
        "stride": (InputConfig, "stride"),
    }
    for option, (section, field) in expected.items():
        assert run[option].default == section.model_fields[field].default, option
    assert run["semantics"].default == SemanticsConfig.model_fields["source"].default.value
    assert run["maps"].default == ",".join(k.value for k in MappingConfig.model_fields["maps"].default)
    assert run["poses"].default == PosesConfig.model_fields["source"].default == GROUND_TRUTH
    for command in ("demo", "batch"):
        assert _options(command)["resolution"].default == MappingConfig.model_fields["resolution"].default


@pytest.mark.parametrize(("args", "message"), [
    (["--segmenter", "segnet"], "invalid --segmenter: unknown segmenter 'segnet'; choose from "),
    (["--instances", "yolo"], "invalid --instances: unknown instance source 'yolo'; choose from "),
    (["--maps", "octomap,mesh"], "--maps: unknown map 'mesh'; choose from octomap, voxelgrid, points"),
    (["--format", "kitti"], "invalid --format: unknown dataset format 'kitti'; choose from auto, "),
    (["--semantics", "magic"], "invalid --semantics: Input should be 'auto', "),
    (["--backend", "magic"], "invalid --backend: "),
])
def test_cli_refuses_an_unknown_name_in_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    result = CliRunner().invoke(app, ["run", str(tmp_path), "--out", str(tmp_path / "out"), *args])
    assert isinstance(result.exception, SemmapError)
    assert str(result.exception).startswith(message) and "\n" not in str(result.exception)
    assert not (tmp_path / "out").exists()


def test_formats_are_found_in_their_own_files(tmp_path: Path) -> None:
    for name, entry in FORMATS.items():
        module = entry.factory.__module__
        assert module.startswith("semmap.datasets.") and module.rsplit(".", 1)[1] in (name, "sevenscenes"), name
    (tmp_path / "rgb.txt").write_text("")
    (tmp_path / "depth.txt").write_text("")
    assert detect_format(tmp_path) == "tum"
