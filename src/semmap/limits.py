"""One table of limits for every numeric option, and the memory budget checked before big allocations.

The CLI, the run configuration (``config.py``) and the library read the same :data:`LIMITS`, so an option is
refused in one line wherever it enters, and NaN or infinite values never reach a numba kernel. Memory that one
option controls (particles, network input, frames, batches, map cells) is estimated with :func:`check_memory`
before it is allocated and refused beyond the budget: ``--memory-budget``, else ``SEMMAP_MEMORY_BUDGET``, else
75 % of the memory available now (``MemAvailable`` of ``/proc/meminfo``).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

from semmap.errors import ConfigError, FormatError

#: Environment variable holding the memory budget (bytes, or a size like ``4G``, ``512M``).
BUDGET_ENV = "SEMMAP_MEMORY_BUDGET"
#: Share of the available memory one command may plan to use when no budget is given.
DEFAULT_BUDGET_SHARE = 0.75


class MemoryBudgetError(ConfigError):
    """An option asks for more memory than the budget allows (the message holds the estimate)."""


@dataclass(frozen=True)
class Limit:
    """The accepted range of one numeric option (inclusive) and what it measures."""

    lo: float
    hi: float
    what: str
    integer: bool = False


#: Every numeric option semmap accepts, by name (the option's name without ``--``, underscores as in the config).
LIMITS: dict[str, Limit] = {
    "resolution": Limit(0.001, 10.0, "voxel size (m)"),
    "point_resolution": Limit(0.001, 1.0, "point-map filter cell (m)"),
    "min_depth": Limit(0.0, 1000.0, "depth (m)"),
    "max_depth": Limit(0.001, 1000.0, "depth (m)"),
    "max_range": Limit(-1.0, 1000.0, "range (m), -1 = none"),
    "depth_scale": Limit(1e-6, 1e6, "depth units per metre"),
    "pixel_stride": Limit(1, 16, "pixels", integer=True),
    "stride": Limit(1, 1_000_000, "frames", integer=True),
    "max_frames": Limit(1, 10_000_000, "frames", integer=True),
    "frames": Limit(1, 1_000_000, "frames", integer=True),
    "k": Limit(1, 8, "classes per voxel", integer=True),
    "lam": Limit(0.0, 1.0, "penalty"),
    "confidence": Limit(1e-6, 1.0, "probability"),
    "probability": Limit(0.0, 1.0, "probability"),
    "segment_every": Limit(1, 1_000_000, "frames", integer=True),
    "batch_size": Limit(1, 64, "frames per network batch", integer=True),
    "batch": Limit(1, 4096, "images per step", integer=True),
    "input_side": Limit(16, 8192, "pixels", integer=True),
    "image_side": Limit(16, 8192, "pixels", integer=True),
    "particles": Limit(1, 10_000_000, "particles", integer=True),
    "scan_points": Limit(1, 100_000, "points per scan", integer=True),
    "workers": Limit(1, 4096, "CPUs", integer=True),
    "cpus_per_run": Limit(0.01, 4096, "CPUs"),
    "rate": Limit(1e-3, 10_000.0, "frames per second"),
    "every": Limit(0, 1_000_000, "frames", integer=True),
    "every_positive": Limit(1, 1_000_000, "frames", integer=True),
    "iterations": Limit(1, 10_000_000, "steps", integer=True),
    "rounds": Limit(1, 10, "rounds of mapping and adapting", integer=True),
    "epochs": Limit(0.001, 100_000, "passes over the data"),
    "crf_iterations": Limit(1, 50, "iterations", integer=True),
    "threads": Limit(1, 1024, "threads", integer=True),
    "queue": Limit(1, 10_000, "frames", integer=True),
    "height": Limit(-100.0, 100.0, "camera height (m)"),
    "position": Limit(-1e8, 1e8, "camera position (m from the origin)"),
    "angle_deg": Limit(-180.0, 180.0, "degrees"),
    "noise": Limit(0.0, 10.0, "fraction"),
    "learning_rate": Limit(1e-9, 10.0, "learning rate"),
    "time_diff": Limit(1e-6, 3600.0, "seconds"),
    "timeout": Limit(0.1, 7 * 24 * 3600.0, "seconds"),
    "seed": Limit(0, 2**32 - 1, "random seed", integer=True),  # numpy's legacy generators stop at 2^32 - 1
    "width": Limit(0.001, 4.0, "width multiplier"),
    "resnet_depth": Limit(18, 50, "ResNet depth 18 | 34 | 50", integer=True),
    "num_classes": Limit(2, 65535, "classes; label images hold 16-bit ids", integer=True),
    "label_id": Limit(-1, 65535, "16-bit label id, -1 = none", integer=True),
    "rotation_frames": Limit(1, 1_000_000, "frames", integer=True),
    "pose_number": Limit(-1e5, 1e5, "metres or quaternion component"),
    "memory": Limit(1 << 20, 1 << 50, "bytes of memory"),
    "changes": Limit(0, 50, "objects changed", integer=True),
    "people": Limit(0, 8, "walking people", integer=True),
    "decay": Limit(0.0, 0.99, "share of log-odds lost per frame unseen"),
    "distance": Limit(1e-3, 100.0, "distance (m)"),
    "coordinate": Limit(-1e4, 1e4, "coordinate (m)"),
    "inflation": Limit(0.0, 10.0, "radius (m)"),
    "tsdf_truncation": Limit(1.0, 64.0, "voxels"),
    "tsdf_weight": Limit(1, 10_000, "observations", integer=True),  # a voxel's weight stops there (tsdf.MAX_WEIGHT)
    "temperature": Limit(0.01, 100.0, "softmax temperature, 1 = as the segmenter gives them"),
    "crf_weight": Limit(0.0, 1000.0, "Potts weight"),
    "crf_position_std": Limit(0.001, 100.0, "kernel width (m)"),
    "crf_color_std": Limit(0.01, 1000.0, "kernel width (colour units 0-255)"),
    "crf_normal_std": Limit(0.001, 10.0, "kernel width (distance of unit normals)"),
}

# ------------------------------------------------------------------------------------ command-line options
#: Forms of an option's text: one number, ``WIDTHxHEIGHT``, a short side ``N`` or ``WIDTHxHEIGHT``, a TUM pose
#: ``tx ty tz qx qy qz qw``, a memory size (``4G``).
NUMBER, SIZE, SIDE_OR_SIZE, POSE, BYTES = "number", "size", "side-or-size", "pose", "bytes"
#: ... or a box ``xmin ymin zmin xmax ymax zmax``; the forms made of several numbers, with their count and shape.
REGION = "region"
NUMBER_LISTS = {POSE: (7, "tx ty tz qx qy qz qw"), REGION: (6, "xmin ymin zmin xmax ymax zmax")}


@dataclass(frozen=True)
class OptionRule:
    """How one command-line option's text holds numbers, and the limit (a key of :data:`LIMITS`) of each."""

    limit: str
    form: str = NUMBER


#: Every numeric command-line option of every command, by ``--option`` (or ``COMMAND --option`` where one
#: command's option of that name differs). ``tests/test_cli_options_fuzz.py`` fails for a numeric option missing
#: here, and fuzzes each one.
OPTIONS: dict[str, OptionRule] = {
    # the frames of a sequence
    "--stride": OptionRule("stride"), "--max-frames": OptionRule("max_frames"), "--frames": OptionRule("frames"),
    # mapping
    "--resolution": OptionRule("resolution"), "--point-resolution": OptionRule("point_resolution"),
    "--min-depth": OptionRule("min_depth"), "--max-depth": OptionRule("max_depth"),
    "--max-range": OptionRule("max_range"), "--pixel-stride": OptionRule("pixel_stride"),
    "--top-k": OptionRule("k"), "--lambda": OptionRule("lam"), "--max-confidence": OptionRule("confidence"),
    "--label-confidence": OptionRule("confidence"), "--crf-every": OptionRule("every"),
    "--temperature": OptionRule("temperature"),
    # segmentation
    "--segment-every": OptionRule("segment_every"), "--batch-size": OptionRule("batch_size"),
    "--input-size": OptionRule("input_side", SIDE_OR_SIZE), "train --input-size": OptionRule("input_side", SIZE),
    # the run's loop and outputs
    "--rate": OptionRule("rate"), "--rerun-map-every": OptionRule("every_positive"),
    "--checkpoint-every": OptionRule("every"), "--memory-budget": OptionRule("memory", BYTES),
    # simulate
    "--image-size": OptionRule("image_side", SIZE), "--scene-seed": OptionRule("seed"),
    "--trajectory-seed": OptionRule("seed"), "--seed": OptionRule("seed"),
    # train
    "--epochs": OptionRule("epochs"), "--iterations": OptionRule("iterations"), "--batch": OptionRule("batch"),
    "--lr": OptionRule("learning_rate"), "--width": OptionRule("width"), "--resnet-depth": OptionRule("resnet_depth"),
    "--threads": OptionRule("threads"), "--eval-every": OptionRule("every_positive"),
    "--depth-scale": OptionRule("depth_scale"),
    # adapt, run --adapt
    "--steps": OptionRule("iterations"), "--replay-share": OptionRule("probability"),
    "--min-confidence": OptionRule("probability"), "--min-views": OptionRule("every"),
    "--network-confidence": OptionRule("probability"), "adapt --every": OptionRule("every_positive"),
    "--adapt-rounds": OptionRule("rounds"), "--adapt-steps": OptionRule("iterations"),
    # localize
    "--particles": OptionRule("particles"), "--points": OptionRule("scan_points"),
    "--init-pose": OptionRule("pose_number", POSE), "--motion-noise": OptionRule("noise"),
    "--height": OptionRule("height"), "--pitch-deg": OptionRule("angle_deg"), "--roll-deg": OptionRule("angle_deg"),
    # evaluation
    "--max-time-diff": OptionRule("time_diff"), "--rotation-frames": OptionRule("rotation_frames"),
    "--num-classes": OptionRule("num_classes"), "--ignore": OptionRule("label_id"),
    # batch
    "--workers": OptionRule("workers"), "--cpus-per-run": OptionRule("cpus_per_run"),
    # simulate --changes, diff, export
    "--changes": OptionRule("changes"), "--changes-seed": OptionRule("seed"), "--people": OptionRule("people"),
    "--match-radius": OptionRule("distance"), "--move-threshold": OptionRule("distance"),
    "--z-min": OptionRule("coordinate"), "--z-max": OptionRule("coordinate"), "--floor": OptionRule("coordinate"),
    "--slice-z": OptionRule("coordinate"), "--inflation": OptionRule("inflation"), "--near": OptionRule("distance"),
    "--door-width": OptionRule("distance"), "--region": OptionRule("coordinate", REGION),
    # eval-map, merge
    "eval-map --every": OptionRule("every_positive"), "eval-seg --every": OptionRule("every_positive"),
    "--min-overlap": OptionRule("probability"),
    # the TSDF and its mesh
    "--tsdf-voxel": OptionRule("resolution"), "--tsdf-truncation": OptionRule("tsdf_truncation"),
    "--min-weight": OptionRule("tsdf_weight"),
    # dynamic scenes
    "--decay": OptionRule("decay"),
}


def option_rule(option: str, command: str | None = None) -> OptionRule | None:
    """The rule of ``option`` of ``command`` (None: not a numeric option)."""
    return OPTIONS.get(f"{command} {option}") or OPTIONS.get(option)


def check_option(option: str, value: object, command: str | None = None) -> object:
    """``value`` of the numeric command-line ``option`` parsed (a number, ``(width, height)``, a short side or 7
    pose numbers) and checked against its limit; one :class:`ConfigError` line naming the option otherwise."""
    rule = option_rule(option, command)
    if rule is None:
        raise KeyError(f"{option} has no entry in semmap.limits.OPTIONS")
    if value is None:
        return None
    if rule.form == NUMBER:
        return check(rule.limit, value, option)
    if rule.form == BYTES:
        return parse_size(value, option)
    if rule.form in NUMBER_LISTS:
        count, names = NUMBER_LISTS[rule.form]
        lim = LIMITS[rule.limit]
        try:
            numbers = tuple(float(check(rule.limit, n, option)) for n in str(value).replace(",", " ").split())
        except ConfigError:
            numbers = ()
        if len(numbers) != count:
            raise ConfigError(f"{option} must be {count} finite numbers '{names}' from {_num(lim.lo)} to "
                              f"{_num(lim.hi)}, got {_shown(value)}")
        return numbers
    sides = parse_sides(str(value), option, short_side=rule.form == SIDE_OR_SIZE)
    for side in sides if isinstance(sides, tuple) else (sides,):
        check(rule.limit, side, option)
    return sides


def check_options(command: str, values: dict[str, object]) -> None:
    """Check every numeric option among ``values`` (``--option``: value, as given to ``command``) in order."""
    for option, value in values.items():
        if option_rule(option, command) is not None:
            check_option(option, value, command)


def parse_sides(text: str, option: str = "--input-size", *, short_side: bool = True) -> tuple[int, int] | int:
    """``"512x384"`` -> (512, 384); ``"384"`` -> 384 (a short side, where ``short_side``); unchecked sizes."""
    try:
        if short_side and "x" not in text.lower():
            return int(text)
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        example = "a short side like 384 or a size like 512x384" if short_side else "WIDTHxHEIGHT like 160x120"
        raise ConfigError(f"{option} must be {example}, got {text!r}") from None
    return w, h


def field_bounds(name: str, option: str | None = None) -> dict:
    """Keyword arguments of a pydantic ``Field`` for the limit ``name``: ``ge`` / ``le`` for the schema, and the
    limit's and the command-line ``option``'s names, which the configuration checks first (see ``config.py``)."""
    lim = LIMITS[name]
    return {"ge": lim.lo, "le": lim.hi, "json_schema_extra": {"limit": name, "option": option}}


def check(name: str, value: float | int | None, option: str | None = None) -> float | int | None:
    """``value`` when it is a finite number within the limit ``name`` (None passes), else a :class:`ConfigError`
    naming ``option`` (default ``--name``), the value and the accepted range."""
    if value is None:
        return None
    lim = LIMITS[name]
    label = option or "--" + name.replace("_", "-")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond any float
        number = math.inf
    except (TypeError, ValueError):
        raise ConfigError(f"{label} must be a number, got {_shown(value)}") from None
    kind = "a whole number" if lim.integer else "a finite number" if not math.isfinite(number) else "a number"
    if not math.isfinite(number) or (lim.integer and number != int(number)) or not lim.lo <= number <= lim.hi:
        raise ConfigError(f"{label} must be {kind} from {_num(lim.lo)} to {_num(lim.hi)} ({lim.what}), "
                          f"got {_shown(value)}")
    return value


def _shown(value: object) -> str:
    """``value`` for a one-line message (a huge integer or text cut short)."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def check_file_resolution(value: float, path: object) -> float:
    """A map file's resolution when it lies within the ``resolution`` limit, else a :class:`FormatError` naming
    ``path`` (every map reader: ``.ot``, ``.bt``, ``.semmap``, ``.ply``)."""
    lim = LIMITS["resolution"]
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not (math.isfinite(number) and lim.lo <= number <= lim.hi):
        raise FormatError(f"{path}: resolution must be from {_num(lim.lo)} to {_num(lim.hi)} m, got {value!r} "
                          "(a damaged or foreign file?)")
    return number


def _num(x: float) -> str:
    return f"{int(x):,}" if float(x).is_integer() else f"{x:g}"


# ---------------------------------------------------------------------------------------------------- memory
_override: int | None = None
_UNITS = {"": 1, "B": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def parse_size(text: str | int | float, what: str = "--memory-budget") -> int:
    """Bytes from ``"4G"``, ``"512M"``, ``"1.5GB"``, ``"1000000"``; a :class:`ConfigError` naming ``what``."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:e[0-9]+)?)\s*([KMGT]?)(?:i?B)?\s*", str(text), re.IGNORECASE)
    if not m:
        raise ConfigError(f"{what} must be a size like 4G, 512M or a number of bytes, got {_shown(text)}")
    size = float(m.group(1)) * _UNITS[m.group(2).upper()]
    lim = LIMITS["memory"]
    if not (math.isfinite(size) and lim.lo <= size <= lim.hi):
        raise ConfigError(f"{what} must be a size from {_size_text(lim.lo)} to {_size_text(lim.hi)}, "
                          f"got {_shown(text)}")
    return int(size)


def _size_text(n: float) -> str:
    """``1M``-style text of a whole number of bytes."""
    unit = next(u for u in "TGMK" if n % _UNITS[u] == 0)
    return f"{int(n) // _UNITS[unit]}{unit}"


def set_memory_budget(budget: str | int | None) -> None:
    """Use ``budget`` (bytes or a size like ``4G``; None: back to the environment or the default) from now on."""
    global _override
    _override = None if budget is None else parse_size(budget)


def available_memory() -> int:
    """Bytes the system can still give (``MemAvailable``); the physical memory where that is not known."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def memory_budget() -> tuple[int, str]:
    """The budget in bytes and where it comes from (for the message)."""
    if _override is not None:
        return _override, "--memory-budget"
    env = os.environ.get(BUDGET_ENV)
    if env:
        return parse_size(env, BUDGET_ENV), BUDGET_ENV
    return int(available_memory() * DEFAULT_BUDGET_SHARE), f"{DEFAULT_BUDGET_SHARE:.0%} of the available memory"


def human(n: float) -> str:
    """``1.5 GB``-style size."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{int(n)} B"


def check_memory(what: str, estimate: float) -> None:
    """Refuse (:class:`MemoryBudgetError`, one line with the estimate) when ``what`` needs more than the budget."""
    budget, source = memory_budget()
    if not math.isfinite(estimate) or estimate > budget:
        raise MemoryBudgetError(f"{what} needs about {human(estimate)} of memory, over the budget of "
                                f"{human(budget)} ({source}); lower it, or raise the budget with --memory-budget "
                                f"or {BUDGET_ENV}")


#: Bytes per particle of the particle filter (rotation, translation, weights, scores, motion noise; measured
#: 237 B with 10^8 particles).
BYTES_PER_PARTICLE = 256
#: Bytes per input pixel and image of a network's forward pass (activations; measured 43 B at 20000x20000) ...
BYTES_PER_INFERENCE_PIXEL = 64
#: ... and of a training step (activations kept for the backward pass, gradients, the batch itself).
BYTES_PER_TRAINING_PIXEL = 512
#: Bytes per voxel of a map cell a scan may touch (octree node, log-odds, top-k classes; measured 48 B).
BYTES_PER_VOXEL = 48


def check_particles(particles: int) -> None:
    """Validate ``--particles`` and its memory."""
    check("particles", particles)
    check_memory(f"--particles {particles:,}", particles * BYTES_PER_PARTICLE)


def check_network_input(width: int, height: int, batch: int, *, training: bool = False,
                        option: str = "--input-size") -> None:
    """Validate a network input size and its batch, and the memory of one forward (or training) pass."""
    check("input_side", width, option)
    check("input_side", height, option)
    per_pixel = BYTES_PER_TRAINING_PIXEL if training else BYTES_PER_INFERENCE_PIXEL
    check_memory(f"{option} {width}x{height} with a batch of {batch}", width * height * batch * per_pixel)


def check_map_extent(resolution: float, extent_m: tuple[float, float, float], where: str) -> float:
    """Refuse a map whose cells over ``extent_m`` (x, y, z metres of the scene, ``where`` says how it was
    estimated) at ``resolution`` would not fit the budget; the number of cells otherwise."""
    check("resolution", resolution)
    cells = math.prod(max(float(e), resolution) / resolution for e in extent_m)
    size = "x".join(f"{e:.1f}" for e in extent_m)
    check_memory(f"--resolution {resolution:g} over {where} of {size} m ({cells:,.0f} cells)",
                 cells * BYTES_PER_VOXEL)
    return cells


def check_map_growth(resolution: float, held: int, growth: int, where: str) -> None:
    """Refuse to go on once the maps (``held`` bytes, grown ``growth`` with the last frame, ``where`` names it) would
    pass the budget with one more such frame: the whole run's memory, not only the first view's."""
    budget, source = memory_budget()
    if held + max(growth, 0) > budget:
        raise MemoryBudgetError(f"--resolution {resolution:g}: the maps hold {human(held)} after {where} and grew "
                                f"{human(max(growth, 0))} with it, past the budget of {human(budget)} ({source}); "
                                f"choose a coarser --resolution, fewer frames, or raise the budget with "
                                f"--memory-budget or {BUDGET_ENV}")


#: Bytes of the dense CRF per element and per element and class (pydensecrf's two permutohedral lattices over six
#: features, the unaries, messages and the posterior; measured 1.2 kB + 70 B per class with 10^5 elements).
BYTES_PER_CRF_ELEMENT = 1280
BYTES_PER_CRF_ELEMENT_CLASS = 80


def check_crf(elements: int, classes: int, what: str) -> None:
    """Refuse a dense CRF over ``elements`` voxels or points of ``classes`` classes (``what`` names the map) whose
    lattices would not fit the budget, before they are built."""
    check_memory(f"--crf over the {elements:,} elements of {what} with {classes} classes",
                 elements * (BYTES_PER_CRF_ELEMENT + classes * BYTES_PER_CRF_ELEMENT_CLASS))


#: Bytes per ground-truth surface voxel while a simulated scene is voxelised for scoring (sample keys, weights and
#: the sort that merges them).
BYTES_PER_GROUND_TRUTH_VOXEL = 64


#: Bytes per simulated frame kept for the whole run (pose, timestamps, file lists) and per pixel of one frame
#: while it is rendered and reduced (colour, depth, labels, instances and the renderer's buffers).
BYTES_PER_SIMULATED_FRAME = 1024
BYTES_PER_RENDERED_PIXEL = 64


def check_simulation(frames: int, image_size: tuple[int, int] | None) -> None:
    """Validate ``simulate --frames`` and ``--image-size`` and the memory of the trajectory and one frame."""
    check("frames", frames)
    pixels = 0
    if image_size is not None:
        check("image_side", image_size[0], "--image-size")
        check("image_side", image_size[1], "--image-size")
        pixels = image_size[0] * image_size[1]
    size = f" at {image_size[0]}x{image_size[1]}" if image_size is not None else ""
    check_memory(f"--frames {frames:,}{size}",
                 frames * BYTES_PER_SIMULATED_FRAME + pixels * BYTES_PER_RENDERED_PIXEL)
