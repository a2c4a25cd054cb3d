"""``semmap adapt RUN_DIR`` and ``semmap run SEQ --adapt``: a finished run's map teaches its segmenter
(:mod:`semmap.train.adapt`), and the loop that maps, adapts and maps again.

The run folder says what to read (``config.json``: the sequence, its frames, the segmenter and its weights; the
primary map's ``.semmap``; ``trajectory.txt``: the poses the map was built with); only semmap's own trained
networks can be fine-tuned, any other segmenter is refused in one line before any work. The loop writes each
round into its own folder of ``--out`` (``round-0``, ``adapt-1``, ``round-1``, ...) and a table of the rounds
(``rounds.json``, ``rounds.md``); a round whose folder is complete is not done again, so a killed loop continues
where it stopped (an adaptation from its last checkpoint).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from pydantic import ValidationError

from semmap.config import RunConfig
from semmap.errors import ConfigError, FormatError
from semmap.files.atomic import write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.files.safe import read_text_limited
from semmap.limits import check
from semmap.train.adapt import AdaptResult, AdaptSettings, AdaptSource

log = logging.getLogger("semmap")

#: What a round of the loop reports, from its run's ``report.json`` (the map-at-pixel scores and the 3D one; the
#: segmenter's 2D MIoU is ``<segmenter>_miou_2d`` there).
ROUND_KEYS = ("pixel_miou_network", "pixel_miou_map", "pixel_gain", "pixel_coverage", "miou_3d")
#: Folders of the loop's rounds inside ``--out``.
ROUND_DIR, ADAPT_DIR = "round-{}", "adapt-{}"


def read_run_config(run_dir: Path) -> RunConfig:
    """The configuration a finished run recorded (``RUN_DIR/config.json``); one line naming the file otherwise."""
    path = Path(run_dir) / "config.json"
    if not Path(run_dir).is_dir():
        raise ConfigError(f"{run_dir}: not a run folder (semmap run --out writes one)")
    if not path.is_file():
        raise ConfigError(f"{run_dir}: no config.json; is it the folder of a finished semmap run?")
    text = read_text_limited(path, what="run configuration", error=lambda reason: FormatError(f"{path}: {reason}"))
    try:
        return RunConfig.model_validate_json(text)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ()))
        raise FormatError(f"{path}: not a semmap run configuration ({where}: {first.get('msg')})") from None


def trainable_weights(config: RunConfig, run_dir: Path) -> tuple[str, Path]:
    """(segmenter name, weight file) of a run whose segmenter semmap can fine-tune (its own networks and ESPNetv2,
    alone or inside ``NAME+structure``); ConfigError in one line for any other (a user's ONNX or Hugging Face
    model, stored predictions, the oracle, labels from files)."""
    from semmap.perception.registry import ESPNETV2, SEGMENTERS, TRAINED_NETWORKS, shipped_espnetv2, shipped_weights

    s = config.semantics
    name = s.segmenter.value if s.segmenter is not None else None
    trainable = ", ".join((*TRAINED_NETWORKS, ESPNETV2))
    if name is None:
        what = f"--semantics {s.source.value}" if s.source is not None else "no segmenter"
        raise ConfigError(f"{run_dir}: the run took its classes from {what}, not from a network semmap can "
                          f"fine-tune; map with one of {trainable} (--segmenter) to adapt")
    if not SEGMENTERS[name].trained and name != ESPNETV2:
        shown = f"{name}:{s.model}" if s.model else name
        raise ConfigError(f"{run_dir}: the run's segmenter {shown} cannot be fine-tuned: semmap adapts only "
                          f"{trainable}; map with one of them (--segmenter) to adapt")
    shipped = shipped_espnetv2() if name == ESPNETV2 else shipped_weights(name)
    weights = Path(s.weights) if s.weights is not None else shipped
    if not weights.is_file():
        raise ConfigError(f"{run_dir}: the run's {name} weights {weights} are not there any more")
    return name, weights


def adapt_source(run_dir: Path, *, command: str = "") -> AdaptSource:
    """What ``semmap adapt`` reads of the finished run in ``run_dir``: refused in one line before any work for a
    segmenter it cannot train, a run without its map or poses, or colour not registered onto depth."""
    from semmap.factories import open_dataset_of
    from semmap.io.map_files import load_map, native_file
    from semmap.io.trajectory import read_trajectory

    run_dir = Path(run_dir)
    config = read_run_config(run_dir)
    name, weights = trainable_weights(config, run_dir)
    if config.input.raw_color:
        raise ConfigError(f"{run_dir}: the run kept colour unregistered (--raw-color); pseudo-labels lie on the "
                          "depth image, so adapt a run made without --raw-color")
    primary = config.mapping.maps[0]
    map_path = run_dir / native_file(primary)
    trajectory_path = run_dir / "trajectory.txt"
    for path, what in ((map_path, "map"), (trajectory_path, "poses the map was built with")):
        if not path.is_file():
            raise ConfigError(f"{run_dir}: no {path.name} (the {what}); is the run finished?")
    m = load_map(map_path)
    dataset = open_dataset_of(config.input)
    return AdaptSource(run_dir=run_dir, frames=lambda: iter(dataset), length=len(dataset),
                       trajectory=read_trajectory(trajectory_path), map=m, weights=weights, segmenter=name,
                       min_depth=config.mapping.min_depth, max_depth=config.mapping.max_depth, command=command)


def adapt_run(run_dir: Path, settings: AdaptSettings, *, resume: bool = False,
              progress: Callable[[str, int, int], None] | None = None, command: str = "") -> AdaptResult | None:
    """``semmap adapt RUN_DIR --out DIR``: the run's network fine-tuned on its map's pseudo-labels."""
    from semmap.train.adapt import adapt

    check_outputs([("--out", settings.out, OutputKind.FOLDER)], [("RUN_DIR", run_dir)])
    return adapt(adapt_source(run_dir, command=command), settings, resume=resume, progress=progress)


@dataclass
class LoopResult:
    """The rounds of ``semmap run --adapt``: a row per mapping round and the folder of each."""

    out: Path
    rows: list[dict] = field(default_factory=list)
    weights: Path | None = None  #: the last adaptation's weights (for --weights)


def round_row(index: int, report: dict, weights: Path | None, adapted: dict | None) -> dict:
    """One round of the loop: the weights it mapped with and its run's scores (and the adaptation before it)."""
    row = {"round": index, "weights": None if weights is None else str(weights)}
    row.update({key: report.get(key) for key in ROUND_KEYS if report.get(key) is not None})
    segmenter = report.get("segmenter")
    if segmenter and report.get(f"{segmenter}_miou_2d") is not None:
        row["miou_2d"] = report[f"{segmenter}_miou_2d"]
    if adapted:
        p = adapted.get("pseudo_labels", {})
        row.update({"pseudo_coverage": p.get("coverage"), "pseudo_accuracy": p.get("accuracy"),
                    "adapt_cpu_minutes": adapted.get("cpu_minutes"), "adapt_best_step": adapted["best"].get("step")})
    return row


def run_with_adaptation(config: RunConfig, rounds: int, settings: AdaptSettings, *,
                        run: Callable[[RunConfig], object],
                        adapt: Callable[[Path, AdaptSettings, bool], AdaptResult | None] | None = None) -> LoopResult:
    """Map ``config``'s sequence, then ``rounds`` times: adapt the segmenter on the last map and map again with the
    adapted weights; each round in its folder of ``config.output.out``. ``run`` maps one configuration (the
    runner's ``run_config``) and returns its result; ``adapt(run_dir, settings, resume)`` adapts (default
    :func:`adapt_run`); ``settings.out`` is replaced by each round's folder."""
    check("rounds", rounds, "--adapt-rounds")
    out = Path(config.output.out)
    trainable_weights(config, out)  # refused before any mapping
    check_outputs([("--out", out, OutputKind.FOLDER)], [("DATASET", config.input.dataset)])
    out.mkdir(parents=True, exist_ok=True)
    adapt = adapt or (lambda run_dir, s, resume: adapt_run(run_dir, s, resume=resume))
    result = LoopResult(out)
    current, adapted = config.model_copy(deep=True), None
    for index in range(rounds + 1):
        round_out = out / ROUND_DIR.format(index)
        current = current.model_copy(update={"output": current.output.model_copy(update={"out": round_out})})
        report = _finished_round(round_out, current)
        if report is None:
            report = run(current).report
        result.rows.append(round_row(index, report, current.semantics.weights, adapted))
        _write_rounds(out, result.rows)
        if index == rounds:
            break
        adapt_out = out / ADAPT_DIR.format(index + 1)
        adapted = _finished_adaptation(adapt_out)
        if adapted is None:
            adapted = adapt(round_out, replace(settings, out=adapt_out), (adapt_out / "last.pt").is_file()).report
        result.weights = Path(adapted["out"])
        semantics = current.semantics.model_copy(update={"weights": result.weights})
        current = current.model_copy(update={"semantics": semantics})
    return result


def _finished_round(folder: Path, config: RunConfig) -> dict | None:
    """The report of a round already mapped with this configuration (None: map it)."""
    try:
        if json.loads((folder / "config.json").read_text()) != json.loads(config.to_json()):
            return None
        return json.loads((folder / "report.json").read_text())
    except (OSError, ValueError):
        return None


def _finished_adaptation(folder: Path) -> dict | None:
    """The report of an adaptation already finished in ``folder`` (None: adapt, or continue from its checkpoint)."""
    try:
        report = json.loads((folder / "report.json").read_text())
    except (OSError, ValueError):
        return None
    return report if Path(report.get("out", "")).is_file() else None


def _write_rounds(out: Path, rows: list[dict]) -> None:
    """``rounds.json`` and ``rounds.md``: the loop's table so far."""
    write_text_atomic(out / "rounds.json", json.dumps({"rounds": rows}, indent=2))
    lines = ["# semmap run --adapt", "", "| round | weights | network (pixel MIoU) | map (pixel MIoU) | gain | "
             "3D mIoU | pseudo-label coverage | adaptation CPU min |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['round']} | {r['weights'] or 'as given'} | {_f(r.get('pixel_miou_network'))} | "
                     f"{_f(r.get('pixel_miou_map'))} | {_f(r.get('pixel_gain'))} | {_f(r.get('miou_3d'))} | "
                     f"{_f(r.get('pseudo_coverage'))} | {_f(r.get('adapt_cpu_minutes'), '.1f')} |")
    write_text_atomic(out / "rounds.md", "\n".join(lines) + "\n")


def _f(v, spec: str = ".3f") -> str:
    return "-" if v is None else format(v, spec)
