"""What the commands show on the terminal: the stderr console, logging, progress bars, summary tables, the
Ctrl-C line and the small formatters of their numbers."""

from __future__ import annotations

import contextlib
import json
import logging
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import typer


def stderr_console():
    from rich.console import Console

    return Console(stderr=True)


def setup_logging(verbose: bool) -> None:
    """Rich log lines on a terminal; plain one-line ``semmap: warning: ...`` messages otherwise (logs, CI)."""
    if sys.stderr.isatty():
        from rich.logging import RichHandler

        handler: logging.Handler = RichHandler(console=stderr_console(), show_time=False, show_path=False, markup=False)
        fmt = "%(message)s"
    else:
        handler = logging.StreamHandler(sys.stderr)
        fmt = "semmap: %(levelname)s: %(message)s"
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format=fmt, handlers=[handler],
                        force=True)
    logging.getLogger("numba").setLevel(logging.WARNING)
    logging.getLogger("numexpr").setLevel(logging.WARNING)  # "NumExpr defaulting to N threads" (via rerun/pandas)


def progress_bar(description: str):
    """A rich progress wrapper ``(iterator, total) -> iterator`` for long loops."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    def wrap(it: Iterator, total: int) -> Iterator:
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[rate]}"), TimeRemainingColumn(), console=stderr_console(),
                      transient=False) as progress:
            task = progress.add_task(description, total=total, rate="")
            import time

            t0 = time.perf_counter()
            for i, item in enumerate(it, 1):
                yield item
                rate = i / max(time.perf_counter() - t0, 1e-9)
                progress.update(task, advance=1, rate=f"{rate:.1f} frames/s")

    return wrap


@contextlib.contextmanager
def interruptible():
    """Ctrl-C: one line saying after which frame the run stopped and what was kept, and exit code 130 (typer would
    exit 130 silently, and a Ctrl-C inside a numba kernel would show a SystemError)."""
    from semmap.interrupt import RunInterrupted

    try:
        yield
    except RunInterrupted as exc:
        print(f"semmap: {exc}", file=sys.stderr)
        raise typer.Exit(130) from None
    except KeyboardInterrupt:
        print("semmap: interrupted", file=sys.stderr)
        raise typer.Exit(130) from None
    except SystemError as exc:
        if not isinstance(exc.__cause__ or exc.__context__, KeyboardInterrupt):
            raise
        print("semmap: interrupted", file=sys.stderr)
        raise typer.Exit(130) from None


def print_table(title: str, rows: list[tuple[str, str]]) -> None:
    """The summary table every command prints (on stderr, beside its progress bars; ``--json`` is for scripts)."""
    from rich.table import Table

    t = Table(title=title, show_header=False)
    for key, value in rows:
        t.add_row(key, value)
    stderr_console().print(t)


def summary_out(summary: dict, as_json: bool, title: str, rows: list[tuple[str, str]]) -> None:
    """A command's result: the full JSON on stdout with ``--json``, else the table of its main numbers."""
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
    else:
        print_table(title, rows)


def cm(metres: float | None) -> str:
    return "-" if metres is None else f"{100 * metres:.2f} cm"


class ProgressCallback:
    """A rich progress bar driven by ``callback(i, n)`` calls (for library functions that report progress)."""

    def __init__(self, description: str, total: int) -> None:
        self.description, self.total = description, total

    def __enter__(self):
        self._progress = None
        return self._update

    def _update(self, i: int, n: int) -> None:
        """Start the bar on the first report (a refusal before any work shows only its one line)."""
        if self._progress is None:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self._progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                      TimeRemainingColumn(), console=stderr_console())
            self._progress.__enter__()
            self._task = self._progress.add_task(self.description, total=self.total)
        self._progress.update(self._task, completed=i, total=n)

    def __exit__(self, *exc):
        return None if self._progress is None else self._progress.__exit__(*exc)


def sim3_scale(value: float | None) -> str:
    """A Sim(3) scale, or why there is none (a static camera cannot be aligned)."""
    return "- (alignment not possible)" if value is None else f"{value:.4f}"


def print_summary(report: dict, out_dir: Path) -> None:
    from semmap.eval.headline import accuracy_rows

    rows = [(key, str(report[key])) for key in ("frames_used", "frames_skipped", "occupied_voxels", "free_voxels",
                                                "occupied_leaves", "free_leaves", "bytes_in_memory", "semantics",
                                                "frames_segmented")
            if key in report]
    rows += accuracy_rows(report)  # the map vs its network at the same pixels first, the 3D map apart
    if "trajectory_vs_ground_truth" in report:
        ate = report["trajectory_vs_ground_truth"]["ate_rmse_m"]
        rows.append(("ATE of the poses used", f"{100 * ate:.2f} cm"))
    if "continued" in report:
        c = report["continued"]
        rows.append(("continued from", f"{c['prior']}: localized after {c['converged_after_frames']} frames, ICP "
                                       f"residual {100 * c['icp'].get('rms_residual_m', 0.0):.2f} cm"))
    if "online" in report:
        o = report["online"]
        rows.append(("online", f"{o['fps']:.1f} frames/s, latency {o['latency_ms']['median']:.0f} ms (median), "
                               f"drift left in {o['drift_left_in']['max_mm']:.1f} mm (max)"))
    top = list(report.get("voxels_per_class", {}).items())[:8]
    if top:
        rows.append(("voxels per class", ", ".join(f"{name} {n:,}" for name, n in top)))
    rows += [(f"size of {name}", f"{size:,} B") for name, size in report.get("bytes_on_disk", {}).items()]
    rows.append(("ms per frame", f"{report['ms_per_frame']['total']:.1f}"))
    print_table(f"semmap: {out_dir}", rows)


def exit_on_errors(call: Callable[[], object], prog: str = "semmap") -> None:
    """``call()`` as a command line runs it: a known error (``SemmapError``, a failed write) becomes one line
    ``PROG: error: ...`` on stderr and exit code 1, Ctrl-C one line and 130; tracebacks are left for bugs (the
    ``semmap`` entry point and the user scripts in ``scripts/``)."""
    from semmap.errors import SemmapError

    try:
        call()
    except SemmapError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        sys.exit(1)
    except OSError as exc:  # a full disk, a read-only file system, a refused name: one line, not a traceback
        from semmap.files.outputs import write_failure

        if (error := write_failure(exc)) is None:
            raise
        print(f"{prog}: error: {error}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt as exc:
        from semmap.interrupt import RunInterrupted

        print(f"{prog}: {exc}" if isinstance(exc, RunInterrupted) else f"{prog}: interrupted", file=sys.stderr)
        sys.exit(130)
    except SystemError as exc:  # a second Ctrl-C inside a numba kernel surfaces as SystemError
        if not isinstance(exc.__cause__ or exc.__context__, KeyboardInterrupt):
            raise
        print(f"{prog}: interrupted", file=sys.stderr)
        sys.exit(130)
