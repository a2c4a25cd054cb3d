"""The output policy every command follows, checked before any work: an output never is, contains or lies inside an
input of the command; only a regular file (a file output) or a folder (a folder output) is ever replaced; its name is
UTF-8 and short enough for the temporary names beside it; and its folder can be written.

A command lists its outputs and inputs as ``(option, path)`` pairs (``("--out", out)``, ``("DATASET", seq)``) and
calls :func:`check_outputs`; a refusal is one :class:`~semmap.errors.OutputError` line naming the option.
"""

from __future__ import annotations

import errno
import os
import re
import stat
from collections.abc import Iterable, Sequence
from enum import Enum
from pathlib import Path

from semmap.errors import OutputError

#: Bytes a file or folder name may have (ext4, xfs, btrfs, tmpfs); ``.NAME.partial`` and ``.NAME.XXXXXXXX.tmp``
#: beside an output need the slack below.
NAME_MAX = 255
#: Room left in an output's name for the staging and temporary names made from it.
NAME_SLACK = 24
#: Bytes a whole path may have (Linux ``PATH_MAX`` less the slack).
PATH_MAX = 4096 - NAME_SLACK
#: errno values of a write that failed for a reason outside semmap (the disk, the permissions, the name).
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENAMETOOLONG,
                          errno.EISDIR, errno.ENOTDIR, errno.EEXIST, errno.EFBIG, errno.EIO, errno.ENOTEMPTY})
#: Free bytes below which an output's folder counts as full: refused before any work (a full disk fails fast).
MIN_FREE_BYTES = 1 << 20
#: What to do about each failure of :data:`WRITE_ERRNOS`.
_SPACE, _ELSEWHERE = "free some space or write elsewhere", "choose another path"
_PERMISSION = "check the permissions, or " + _ELSEWHERE
_WHAT_TO_DO = {errno.ENOSPC: _SPACE, errno.EDQUOT: _SPACE, errno.EFBIG: "write it to another file system",
               errno.EROFS: "write elsewhere", errno.EACCES: _PERMISSION, errno.EPERM: _PERMISSION,
               errno.ENAMETOOLONG: "choose a shorter name", errno.EISDIR: _ELSEWHERE, errno.ENOTDIR: _ELSEWHERE,
               errno.EEXIST: _ELSEWHERE, errno.ENOTEMPTY: _ELSEWHERE, errno.EIO: "check the disk, or " + _ELSEWHERE}
#: Failures only a write meets (the others, a permission or a path, may come from reading too).
_ONLY_WRITES = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EEXIST, errno.ENOTEMPTY})
#: Names semmap writes on the way to an output: a staging folder ``.OUT.partial`` and a temporary file
#: ``.NAME.XXXXXXXX.tmp`` (``tempfile.mkstemp``), shown to the user as the output they stand for.
_ON_THE_WAY = (re.compile(r"^\.(?P<name>.+)\.partial$"), re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}\.tmp$"))

Named = tuple[str, "str | Path | None"]


class OutputKind(Enum):
    """What an output path names: one file, or a folder of files."""

    FILE = "file"
    FOLDER = "folder"


def _resolved(path: str | Path) -> Path:
    """The absolute path with links followed; a link loop stays as written (its reader names the loop later)."""
    absolute = Path(os.path.abspath(Path(path).expanduser()))
    try:
        return absolute.resolve(strict=False)
    except (RuntimeError, OSError):  # Python < 3.13 raises RuntimeError on a symlink loop
        return absolute


def _kind_of(mode: int) -> str:
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a special file"


def check_name(path: str | Path, option: str) -> None:
    """The output's name is UTF-8 (reports and ``config.json`` record it) and short enough for its staging names."""
    check_utf8(path, option)
    text = os.fspath(path)
    raw = os.fsencode(text)
    if b"\0" in raw or not raw:
        raise OutputError(f"{option} {text!r}: not a valid path")
    parts = Path(text).parts
    longest = max((len(os.fsencode(p)) for p in parts), default=0)
    if parts and len(os.fsencode(parts[-1])) > NAME_MAX - NAME_SLACK:
        raise OutputError(f"{option} {text[:60]}...: its name has {len(os.fsencode(parts[-1]))} bytes, more than "
                          f"the {NAME_MAX - NAME_SLACK} an output may have; choose a shorter name")
    if longest > NAME_MAX or len(os.fsencode(os.path.abspath(text))) > PATH_MAX:
        raise OutputError(f"{option} {text[:60]}...: the path is too long; choose a shorter one")


def check_utf8(path: str | Path, option: str) -> None:
    """A path semmap records (``config.json``, reports) must have a UTF-8 name: refused in one line otherwise."""
    try:
        os.fsencode(os.fspath(path)).decode("utf-8")
    except (UnicodeError, TypeError):
        raise OutputError(f"{option} {os.fspath(path)!r}: the name is not UTF-8 text, which the outputs cannot "
                          f"record; rename it (nothing was written)") from None


def check_type(path: str | Path, option: str, kind: OutputKind) -> None:
    """Only a regular file (a file output) or a folder (a folder output) is ever replaced, nor does an output lie
    below a file; the nearest existing folder must be writable."""
    path = Path(path)
    try:
        st = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):  # (below a file: said by the folder walk below)
        st = None
    except OSError as exc:
        raise OutputError(f"{option} {path}: cannot use it ({exc.strerror or exc})") from None
    if st is not None:
        if stat.S_ISDIR(st.st_mode) and kind == OutputKind.FILE:
            raise OutputError(f"{option} {path}: is a folder; give a file name")
        if stat.S_ISREG(st.st_mode) and kind == OutputKind.FOLDER:
            raise OutputError(f"{option} {path}: is a file; give a folder")
        if not (stat.S_ISDIR(st.st_mode) or stat.S_ISREG(st.st_mode)):
            raise OutputError(f"{option} {path}: is {_kind_of(st.st_mode)}, not a regular {kind.value}; semmap "
                              f"replaces only regular files and folders")
    parent = _resolved(path).parent
    for where in (parent, *parent.parents):
        if where.exists():
            if not where.is_dir():
                raise OutputError(f"{option} {path}: lies below {where}, which is a file; give a {kind.value} "
                                  f"in a folder")
            if not os.access(where, os.W_OK | os.X_OK):
                why = "read-only file system" if _read_only(where) else "permission denied"
                raise OutputError(f"{option} {path}: cannot write in {where} ({why})")
            free = free_bytes(where)
            if free is not None and free < MIN_FREE_BYTES:
                raise OutputError(f"{option} {path}: no space left on the device of {where} ({free // 1024} KB "
                                  f"free); free some space or choose another {option} (nothing was written)")
            return


def _read_only(folder: Path) -> bool:
    try:
        return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def free_bytes(folder: str | Path) -> int | None:
    """Bytes this process may still write in ``folder``'s file system (root also the reserved blocks), or None
    when the system does not say."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return None
    blocks = st.f_bfree if hasattr(os, "geteuid") and os.geteuid() == 0 else st.f_bavail
    return int(blocks) * int(st.f_frsize)


def check_not_input(path: str | Path, option: str, inputs: Iterable[Named]) -> None:
    """``path`` is not any input, does not lie inside an input folder and does not contain an input."""
    out = _resolved(path)
    for name, given in inputs:
        if given is None or str(given) == "":
            continue
        src = _resolved(given)
        if out == src:
            raise OutputError(f"{option} {path}: is the input {name} {given}; writing there would destroy it "
                              f"(nothing was written); choose another {option}")
        if out.is_relative_to(src):
            raise OutputError(f"{option} {path}: lies inside the input {name} {given} (nothing was written); "
                              f"choose a {option} outside it")
        if src.is_relative_to(out):
            raise OutputError(f"{option} {path}: contains the input {name} {given}, which replacing it would "
                              f"destroy (nothing was written); choose another {option}")


def check_outputs(outputs: Sequence[tuple[str, str | Path | None, OutputKind]], inputs: Iterable[Named]) -> None:
    """Every output of a command against the policy (name, type, writable folder, inputs) and against each other
    (two options naming one path); ``None`` outputs (options not given) are skipped."""
    inputs = [(n, p) for n, p in inputs if p is not None]
    given = [(option, Path(path), kind) for option, path, kind in outputs if path is not None]
    for option, path, kind in given:
        check_name(path, option)
        check_type(path, option, kind)
        check_not_input(path, option, inputs)
    for i, (option, path, _) in enumerate(given):
        for other, path2, _ in given[i + 1:]:
            if _resolved(path) == _resolved(path2):
                raise OutputError(f"{option} and {other} name the same path {path}; give each its own")


def shown_path(path: str | Path) -> str:
    """``path`` as the user named it: a staging folder ``.OUT.partial`` or a temporary ``.NAME.XXXXXXXX.tmp`` in it
    is shown as the output it stands for (``full/.run.partial/map.ot`` -> ``full/run/map.ot``)."""
    parts = [next((m["name"] for rx in _ON_THE_WAY if (m := rx.match(part))), part) for part in Path(path).parts]
    return str(Path(*parts)) if parts else os.fspath(path)


def write_failure(exc: OSError, what: str | Path = "") -> OutputError | None:
    """One line naming the file and what to do for a write the disk or the system refused (full, read-only,
    permissions, name too long, something in the way), or None when ``exc`` is something else (a bug to show in
    full). ``what`` names the file when the error does not; "cannot write" only where a write it must have been."""
    if exc.errno not in WRITE_ERRNOS:
        return None
    given = exc.filename if isinstance(exc.filename, str | bytes | os.PathLike) and exc.filename else what
    where = shown_path(os.fsdecode(given)) if given else "an output"
    kept = " (nothing was replaced)" if given and where != os.fsdecode(given) else ""  # (a staging folder's file)
    reason = exc.strerror or os.strerror(exc.errno)
    what_failed = f"cannot write {where}" if exc.errno in _ONLY_WRITES or kept else where
    return OutputError(f"{what_failed}: {reason}; {_WHAT_TO_DO[exc.errno]}{kept}")
