"""The on-disk life of one run's outputs: written into a staging folder beside ``--out`` and moved into place only
when every file is there, checkpoints kept in that folder, and a run killed half-way resumed from it.

``.OUT.partial`` (beside ``OUT``) holds the files while the run writes them, ``owner`` (the pid of the run writing
there) and ``checkpoint.npz`` (the run's state after some frame). ``commit()`` renames the staging folder to
``OUT`` (an earlier ``OUT`` is moved aside first and removed after), so ``OUT`` only ever holds one complete run.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from semmap.errors import ConfigError

LOG = logging.getLogger("semmap")
T = TypeVar("T")
CHECKPOINT = "checkpoint.npz"
OWNER = "owner"


def check_out_dir(out: Path) -> None:
    """``--out`` must be a folder or not exist yet (nor lie below a file): checked before any frame is mapped."""
    for where in (out, *out.parents):
        if where.exists():
            if not where.is_dir():
                what = "is a file" if where == out else f"lies below {where}, which is a file"
                raise ConfigError(f"--out {out}: {what}; give a folder (nothing was mapped)")
            return


def staging_folder(out: Path) -> Path:
    """Where a run into ``out`` writes before its outputs are complete."""
    return out.parent / f".{out.name}.partial"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class StagedRun:
    """Staging folder, checkpoints and the final move of one run's outputs."""

    def __init__(self, out: Path, *, resume: bool = False) -> None:
        self.out = Path(out)
        self.stage = staging_folder(self.out)
        self.resume = resume
        self.committed = False

    # ------------------------------------------------------------------ start
    def open(self) -> Path:
        """Claim the staging folder (refusing one a live run owns); without ``resume`` an old one is cleared."""
        owner = self.stage / OWNER
        if owner.is_file():
            try:
                pid = int(owner.read_text().strip() or 0)
            except (OSError, ValueError):
                pid = 0
            if pid and pid != os.getpid() and _alive(pid):
                raise ConfigError(f"--out {self.out}: another semmap run (pid {pid}) is writing there now")
        if self.stage.exists() and not self.resume:
            shutil.rmtree(self.stage)  # what a crashed run left behind; only --resume picks it up
        created = not self.stage.exists()
        try:
            self.stage.mkdir(parents=True, exist_ok=True)
            owner.write_text(str(os.getpid()))
        except OSError as exc:  # a full disk: no empty staging folder left behind, and the output named
            if created:
                shutil.rmtree(self.stage, ignore_errors=True)
            if exc.errno is None:
                raise
            raise OSError(exc.errno, exc.strerror, os.fspath(self.out)) from None
        return self.stage

    # ------------------------------------------------------------------ checkpoints
    @property
    def checkpoint_path(self) -> Path:
        return self.stage / CHECKPOINT

    # ------------------------------------------------------------------ end
    def commit(self) -> None:
        """Move the finished outputs into ``out`` (replacing an earlier run's folder as a whole)."""
        for name in (CHECKPOINT, OWNER):
            with contextlib.suppress(FileNotFoundError):
                (self.stage / name).unlink()
        old = self.out.parent / f".{self.out.name}.old-{os.getpid()}"
        if self.out.exists():
            os.replace(self.out, old)
        try:
            os.replace(self.stage, self.out)
        except OSError:
            if old.exists():
                os.replace(old, self.out)  # put the earlier run back rather than leave nothing
            raise
        shutil.rmtree(old, ignore_errors=True)
        self.committed = True

    def abandon(self, *, keep_checkpoint: bool) -> str:
        """After a failure or an interruption: remove the staging folder, or keep it when it holds a checkpoint to
        resume from; returns what was kept, for the user."""
        if self.committed:
            return "outputs written"
        if keep_checkpoint and self.checkpoint_path.is_file():
            with contextlib.suppress(FileNotFoundError):
                (self.stage / OWNER).unlink()
            return f"{self.out} untouched; checkpoint kept in {self.stage} (continue with --resume)"
        shutil.rmtree(self.stage, ignore_errors=True)
        return "nothing written"


def run_staged(out: Path, write: Callable[[Path], T]) -> T:
    """A folder of outputs written like a run's: ``write(stage)`` fills the staging folder, which replaces ``out``
    as a whole once complete; a failure (a full disk) or Ctrl-C leaves ``out`` as it was. Returns what ``write``
    returned."""
    staged = StagedRun(Path(out))
    stage = staged.open()
    try:
        result = write(stage)
        staged.commit()
    except BaseException:
        staged.abandon(keep_checkpoint=False)
        raise
    return result


def write_staged(out: Path, write: Callable[[Path], dict[str, Path]]) -> dict[str, Path]:
    """:func:`run_staged` for a ``write`` that returns ``{name: path}``; the paths come back inside ``out``."""
    stage = staging_folder(Path(out))
    files = run_staged(out, write)
    return {name: Path(out) / Path(path).relative_to(stage) for name, path in files.items()}
