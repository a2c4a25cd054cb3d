"""Many sequences, many machines: one ``semmap run`` per sequence as a Ray task, on a local Ray cluster or an existing
one (``address``), resuming a half-finished batch, with one summary table (``batch.json``, ``batch.md``).

Each task runs :func:`semmap.runner.run_config` on a copy of one configuration with its own dataset and output
folder, so a batch's outputs are those of separate ``semmap run``s. A sequence counts as done when its folder holds
the report of a run with the same configuration and every file that report lists.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from semmap.config import RunConfig
from semmap.errors import ConfigError, SemmapError
from semmap.files.atomic import write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.limits import check

LOG = logging.getLogger("semmap")
#: Logical CPUs one run asks of a Ray node (a run's numba and torch threads use about two).
DEFAULT_CPUS_PER_RUN = 2
#: The longest a batch waits for its next sequence to finish before it stops with one line (seconds).
WAIT_TIMEOUT_S = 6 * 3600.0
#: Files of a finished run besides those its report lists.
RUN_FILES = ("report.json", "config.json")


class Status:
    """What happened to one sequence of a batch."""

    DONE = "done"  # mapped by this batch
    RESUMED = "already done"  # complete outputs of the same configuration found: skipped
    FAILED = "failed"


@dataclass(frozen=True)
class BatchItem:
    """One sequence of a batch and the folder its outputs go to."""

    dataset: Path
    out: Path

    @property
    def name(self) -> str:
        return self.out.name


@dataclass
class BatchRow:
    """One line of the summary table."""

    sequence: str
    dataset: str
    out: str
    status: str
    seconds: float | None = None
    frames_used: int | None = None
    ms_per_frame: float | None = None
    occupied_voxels: int | None = None
    miou_3d: float | None = None
    ate_cm: float | None = None
    node: str | None = None
    error: str | None = None
    extra: dict = field(default_factory=dict)


def plan(datasets: list[Path], out_root: Path) -> list[BatchItem]:
    """Output folder per sequence: ``out_root/<folder or bag name>``, made unique with the parent's name."""
    if not datasets:
        raise ConfigError("semmap batch needs at least one sequence")
    check_outputs([("--out", out_root, OutputKind.FOLDER)], [("DATASET", d) for d in datasets])
    names = [_stem(Path(d)) for d in datasets]
    items = []
    for d, name in zip(datasets, names, strict=True):
        if names.count(name) > 1:
            name = f"{Path(d).resolve().parent.name}-{name}"
        items.append(BatchItem(Path(d), Path(out_root) / name))
    taken = [i.out for i in items]
    if len(set(taken)) != len(taken):
        raise ConfigError(f"two sequences would write to the same folder: {sorted(map(str, taken))}")
    return items


def _stem(path: Path) -> str:
    return path.stem if path.is_file() else path.resolve().name


def config_for(template: RunConfig, item: BatchItem) -> RunConfig:
    """The template with this item's dataset and output folder (no viewer: batch tasks have no screen)."""
    return template.model_copy(update={
        "input": template.input.model_copy(update={"dataset": item.dataset}),
        "output": template.output.model_copy(update={"out": item.out, "rerun": None, "rerun_spawn": False}),
    })


def is_complete(config: RunConfig) -> bool:
    """The output folder holds a finished run of exactly this configuration (its report and every file it lists)."""
    out = config.output.out
    try:
        saved = json.loads((out / "config.json").read_text())
        report = json.loads((out / "report.json").read_text())
    except (OSError, ValueError):
        return False
    if _comparable(saved) != _comparable(json.loads(config.to_json())):
        return False
    listed = set(report.get("bytes_on_disk", {})) | set(RUN_FILES)
    return all((out / name).is_file() for name in listed)


def _comparable(config: dict) -> dict:
    """A configuration with its dataset path resolved and its output folder left out (the folder is the one being
    looked at), so a relative and an absolute spelling of the same run compare equal."""
    config = json.loads(json.dumps(config))
    config.get("output", {}).pop("out", None)
    dataset = config.get("input", {}).get("dataset")
    if dataset:
        config["input"]["dataset"] = str(Path(dataset).resolve())
    return config


def row_of(item: BatchItem, status: str, report: dict | None, *, seconds: float | None = None,
           node: str | None = None, error: str | None = None) -> BatchRow:
    """The summary line of one sequence from its report."""
    row = BatchRow(item.name, str(item.dataset), str(item.out), status, seconds=seconds, node=node, error=error)
    if report:
        row.frames_used = report.get("frames_used")
        row.ms_per_frame = report.get("ms_per_frame", {}).get("total")
        row.occupied_voxels = report.get("occupied_voxels")
        row.miou_3d = report.get("miou_3d")
        traj = report.get("trajectory_vs_ground_truth")
        row.ate_cm = None if not traj else round(100 * traj["ate_rmse_m"], 3)
    return row


def run_item(config_json: str) -> dict:
    """Body of one Ray task: map one sequence; returns its summary line as a dict (errors included, not raised)."""
    from semmap.runner import run_config

    config = RunConfig.model_validate_json(config_json)
    item = BatchItem(config.input.dataset, config.output.out)
    node = _node_name()
    start = time.perf_counter()
    try:
        result = run_config(config, title=f"semmap batch: {item.name}")
    except SemmapError as exc:
        return asdict(row_of(item, Status.FAILED, None, seconds=_since(start), node=node, error=str(exc)))
    except Exception as exc:  # a bug in one run must not lose the other sequences' results
        return asdict(row_of(item, Status.FAILED, None, seconds=_since(start), node=node,
                             error=f"{type(exc).__name__}: {exc}"))
    return asdict(row_of(item, Status.DONE, result.report, seconds=_since(start), node=node))


def _since(start: float) -> float:
    return round(time.perf_counter() - start, 2)


def _node_name() -> str:
    """Host and Ray node of the running task (several nodes may share one host)."""
    try:
        import ray

        node = ray.get_runtime_context().get_node_id()[:8]
    except Exception:  # outside Ray
        node = "local"
    return f"{socket.gethostname()}/{node}"


@dataclass
class BatchResult:
    """A batch's rows, its wall time and the cluster it ran on."""

    rows: list[BatchRow]
    seconds: float
    address: str
    nodes: int

    def to_dict(self) -> dict:
        counts = {s: sum(r.status == s for r in self.rows) for s in (Status.DONE, Status.RESUMED, Status.FAILED)}
        mapped = [r.seconds for r in self.rows if r.status == Status.DONE and r.seconds is not None]
        return {"sequences": len(self.rows), **{k.replace(" ", "_"): v for k, v in counts.items()},
                "seconds": round(self.seconds, 2), "address": self.address, "nodes": self.nodes,
                "seconds_per_sequence": round(sum(mapped) / len(mapped), 2) if mapped else None,
                "rows": [asdict(r) for r in self.rows]}


def run_batch(template: RunConfig, items: list[BatchItem], *, address: str | None = None, workers: int | None = None,
              cpus_per_run: float = DEFAULT_CPUS_PER_RUN, resume: bool = True, on_row=None,
              wait_timeout_s: float = WAIT_TIMEOUT_S) -> BatchResult:
    """Map every item as a Ray task; items with complete outputs of the same configuration are skipped when
    ``resume``. ``address``: an existing cluster (``ray://host:10001``, ``host:6379`` or ``auto``); None starts a
    local one with ``workers`` CPUs. ``on_row(row)`` is called as each sequence finishes; the batch stops with one
    line when none finishes within ``wait_timeout_s``. CPUs a run cannot get are refused before submitting."""
    check("workers", workers)
    check("cpus_per_run", cpus_per_run)
    if not address:  # a local cluster: refused before Ray starts
        _check_cpus(cpus_per_run, workers or os.cpu_count() or 1, "the local cluster")
    import ray

    start = time.perf_counter()
    rows: dict[int, BatchRow] = {}
    todo: list[tuple[int, RunConfig]] = []
    earlier = _earlier_rows(items)
    for k, item in enumerate(items):
        config = config_for(template, item)
        if resume and is_complete(config):
            report = json.loads((item.out / "report.json").read_text())
            before = earlier.get(str(item.out), {})
            rows[k] = row_of(item, Status.RESUMED, report, seconds=before.get("seconds"), node=before.get("node"))
            if on_row:
                on_row(rows[k])
        else:
            todo.append((k, config))
    started_here = False
    if todo:
        started_here = _connect(ray, address, workers)
    try:
        nodes = len([n for n in ray.nodes() if n.get("Alive")]) if todo else 0
        if todo and address:
            _check_cpus(cpus_per_run, _largest_node_cpus(ray), f"the largest node of {address}")
        task = ray.remote(num_cpus=cpus_per_run, max_retries=0)(run_item)
        pending = {task.remote(config.to_json()): k for k, config in todo}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1, timeout=wait_timeout_s)
            if not done:
                raise ConfigError(f"no sequence of the batch finished within {wait_timeout_s:.0f} s "
                                  f"({len(pending)} waiting); the cluster may lack resources or a run hangs")
            k = pending.pop(done[0])
            rows[k] = _row_from_task(ray, done[0], items[k])
            if on_row:
                on_row(rows[k])
    finally:
        if started_here:
            ray.shutdown()
    return BatchResult([rows[k] for k in range(len(items))], time.perf_counter() - start,
                       address or "local", nodes)


def _check_cpus(per_run: float, available: float, where: str) -> None:
    """One line instead of a task Ray would wait for forever."""
    if per_run > available:
        raise ConfigError(f"--cpus-per-run {per_run:g}: one sequence needs {per_run:g} CPUs, {where} has "
                          f"{available:g}; lower --cpus-per-run (or raise --workers)")


def _largest_node_cpus(ray) -> float:
    """CPUs of the cluster's largest live node (a task runs on one node)."""
    return max((float(n.get("Resources", {}).get("CPU", 0.0)) for n in ray.nodes() if n.get("Alive")), default=0.0)


def _earlier_rows(items: list[BatchItem]) -> dict[str, dict]:
    """Rows of an earlier ``batch.json`` in the same output folder, by output folder (for the time a resumed
    sequence took when it was mapped)."""
    rows: dict[str, dict] = {}
    for root in {item.out.parent for item in items}:
        try:
            data = json.loads((root / "batch.json").read_text())
            rows.update({r["out"]: r for r in data.get("rows", []) if isinstance(r, dict) and "out" in r})
        except (OSError, ValueError, TypeError, AttributeError):
            continue
    return rows


def _row_from_task(ray, ref, item: BatchItem) -> BatchRow:
    try:
        return BatchRow(**ray.get(ref))
    except ray.exceptions.RayError as exc:  # the worker died (out of memory, a node lost)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return row_of(item, Status.FAILED, None, error=f"Ray task failed: {first}")


def _connect(ray, address: str | None, workers: int | None) -> bool:
    """Join the cluster at ``address`` or start a local one; True when this call started (and must stop) it."""
    if ray.is_initialized():
        return False
    env = {"PYTHONPATH": os.pathsep.join(p for p in (_source_root(), os.environ.get("PYTHONPATH", "")) if p)}
    options = {"log_to_driver": False, "runtime_env": {"env_vars": env}}
    try:
        if address:
            ray.init(address=address, **options)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, **options)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        where = f"the Ray cluster at {address}" if address else "a local Ray cluster"
        raise ConfigError(f"cannot start or join {where}: {str(exc).splitlines()[0]}") from None
    return True


def _source_root() -> str:
    """The folder that holds the ``semmap`` package the driver runs, so workers on this machine import the same
    code (remote nodes need semmap installed; a path that does not exist there is ignored)."""
    import semmap

    return str(Path(semmap.__file__).resolve().parents[1])


# --------------------------------------------------------------------------------------------------
# Summary
# --------------------------------------------------------------------------------------------------
def write_summary(out_root: Path, result: BatchResult) -> tuple[Path, Path]:
    """``batch.json`` (every row and the totals) and ``batch.md`` (the table) in ``out_root``, atomically."""
    data = result.to_dict()
    json_path = write_text_atomic(out_root / "batch.json", json.dumps(data, indent=2))
    return json_path, write_text_atomic(out_root / "batch.md", render_summary_md(data))


def render_summary_md(data: dict) -> str:
    """The batch table in Markdown."""

    def cell(value, fmt: str = "{}") -> str:
        return "–" if value is None else fmt.format(value)

    lines = ["# semmap batch", "",
             f"{data['sequences']} sequences on {data['address']} ({data['nodes']} Ray nodes): {data['done']} mapped, "
             f"{data['already_done']} already done, {data['failed']} failed, in {data['seconds']:.1f} s"
             + (f"; {data['seconds_per_sequence']:.1f} s per mapped sequence." if data["seconds_per_sequence"]
                else "."), "",
             "| sequence | status | frames | ms/frame | seconds | occupied voxels | 3D mIoU | ATE cm | node |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        status = r["status"] if not r["error"] else f"{r['status']}: {r['error']}"
        lines.append(f"| {r['sequence']} | {status} | {cell(r['frames_used'])} | {cell(r['ms_per_frame'], '{:.1f}')} "
                     f"| {cell(r['seconds'], '{:.1f}')} | {cell(r['occupied_voxels'], '{:,}')} "
                     f"| {cell(r['miou_3d'], '{:.3f}')} | {cell(r['ate_cm'], '{:.2f}')} | {cell(r['node'])} |")
    return "\n".join(lines) + "\n"
