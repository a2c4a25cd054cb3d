"""Re-run every case of the bad-input probe (issue 31), or of the new-surfaces probe (issue 48, ``--probe
new-surfaces``), in a scratch folder made by build_fixtures.py and classify each: ``python
scripts/probes/run_cases.py DIR [--cases REGEX] [--jobs N] [--out RESULTS]``. See docs/probes.md.

Per case: exit code, seconds, peak RSS of the process tree (``os.wait4``), a Python traceback or a segfault in the
output, and the sha256 of every input the command names, before and after (any change is DATA-LOSS)."""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import surfaces

TSV = Path("/work/shared/probes/bad-input-2026-11-25.tsv")
ROW = re.compile(r"^([^\t]+)\trc=(-?\d+)\t([\d.]+)s\t(\d+)MB\ttb=(\d+)\t([^\t]*)\t?(.*)$")
SEMMAP = ".venv/bin/semmap"
#: Options whose value is a path semmap writes (not an input).
OUTPUT_OPTIONS = {"--out", "-o", "--save", "--plot", "--rerun", "--plot-errors"}
#: Cases the probe's report lists as DATA-LOSS (D1-D12; a mechanical rule cannot see them in the TSV).
REPORTED_DATA_LOSS = {"out_is_input", "out_parent_of_input", "view_save_over_input", "et_plot_full",
                      "track_out_over_gt", "rerun_over_input", "evalseg_out_over_gt", "sim_out_existing_seq",
                      "sim_out_existing_run", "sim_out_full"}
#: Cases the report lists as UNCLEAR (U1-U24: a misleading message, or one naming no file).
REPORTED_UNCLEAR = {"run_tum_dup_ts", "static_odometry", "runposes_static", "static_track", "track_zero_depth",
                    "run_tum_label_oob", "run_tum_labels_16bit", "run_tum_ls_few", "run_tum_gt_1e300", "full_rerun",
                    "out_full_rerun", "bag_depth_as_rgb", "w_fcn_garbage", "w_fcn_evil", "w_fcn_evil_raw",
                    "w_esp_evil", "w_esp_garbage", "w_fcn_dir", "w_fcn_devzero", "w_fcn_fifo", "runposes_dir",
                    "loc_map_ot", "cli_res0.002_7s", "info_res_huge_semmap", "b_config_list", "et_gt_badfolder"}
#: The harness's classes that correspond to the report's UNCLEAR.
UNCLEAR_FAMILY = {"NO-NAME", "MULTI-LINE", "UNCLEAR"}
MEMORY_MB = 1024
BIG_FILE = 64 * 2**20
PAGE = os.sysconf("SC_PAGE_SIZE")
CLASSES = ("GOOD", "INVALID", "DATA-LOSS", "SILENT-WRONG", "SEGFAULT", "TRACEBACK", "HANG", "MEMORY", "MULTI-LINE",
           "NO-NAME", "UNCLEAR", "NOT-REPRODUCED", "SKIPPED")
#: A TSV whose rows end in the probe's own class (the new-surfaces probe's) gives it here.
PROBE_CLASS = re.compile(r"\t(GOOD|TRACEBACK|SILENT-WRONG|UNCLEAR|HANG|MEMORY|DATA-LOSS)$")
#: The checkout in the new-surfaces probe's commands.
REPO = Path(__file__).resolve().parents[2]
#: An error line of semmap or of one of its scripts (``calibrate_weights: error: ...``).
ERROR_LINE = re.compile(r"^[\w.-]+: error:")
PROGRESS = re.compile(r"━|frames/s|-:--:--|\d+/\d+\s+\d+:\d\d:\d\d")
ANSI = re.compile(r"\x1b\[[0-9;?]*[a-zA-Z]")


@dataclass
class Case:
    """One TSV row: the command as recorded and the outcome the probe saw."""

    id: str
    rc: int
    seconds: float
    peak_mb: int
    tb: int
    command: str
    output: str
    probe_class: str = ""  # the probe's own class, where its TSV gives one

    @property
    def name(self) -> str:
        return self.id.split("#")[0]

    def original_class(self) -> str:
        """The probe's class of this row, from its rc / traceback flag / peak (DATA-LOSS from the report)."""
        if self.probe_class:
            return self.probe_class
        if self.name in REPORTED_DATA_LOSS:
            return "DATA-LOSS"
        if self.rc in (139, -11):
            return "SEGFAULT"
        if self.tb:
            return "TRACEBACK"
        if self.rc == 124:
            return "HANG"
        if self.rc == 137 or self.peak_mb > MEMORY_MB:
            return "MEMORY"
        if self.name in REPORTED_UNCLEAR:
            return "UNCLEAR"
        if self.rc == 126:
            return "INVALID"  # the probe's own command could not start (setpriv as uid 65534)
        return "GOOD"


@dataclass
class Result:
    id: str
    cls: str
    original: str
    rc: int | None = None
    seconds: float = 0.0
    peak_mb: int = 0
    reason: str = ""
    changed: list[str] = field(default_factory=list)
    command: str = ""
    excerpt: str = ""


def read_cases(path: Path) -> list[Case]:
    """Every row of the probe's TSV (continuation lines of an output excerpt are joined to their row)."""
    cases: list[Case] = []
    seen: dict[str, int] = {}
    lines = path.read_bytes().decode("utf-8", "surrogateescape").split("\n")[1:]
    for line in lines:
        m = ROW.match(line)
        if not m:
            if cases and line.strip():
                cases[-1].output += " " + line.strip()
            continue
        name = m.group(1)
        seen[name] = seen.get(name, 0) + 1
        cid = name if seen[name] == 1 else f"{name}#{seen[name]}"
        output = m.group(7)
        probe = PROBE_CLASS.search(output)
        cases.append(Case(cid, int(m.group(2)), float(m.group(3)), int(m.group(4)), int(m.group(5)),
                          m.group(6).replace("CHECKOUT/", f"{REPO}/"),
                          output[:probe.start()] if probe else output, probe.group(1) if probe else ""))
    return cases


# ------------------------------------------------------------------------------------------------ commands
def split_segments(command: str) -> list[str]:
    """The command's top-level ``;`` / ``&&`` segments (quotes, ``$'...'`` and ``$(...)`` respected)."""
    out, cur, i, quote, depth = [], [], 0, "", 0
    while i < len(command):
        c = command[i]
        if quote:
            if c == "\\" and quote == "$'":
                cur.append(command[i:i + 2])
                i += 2
                continue
            if c == quote[-1]:
                quote = ""
        elif c in "'\"":
            quote = "$'" if c == "'" and cur and cur[-1] == "$" else c
        elif command.startswith("$(", i):
            depth += 1
        elif c == ")" and depth:
            depth -= 1
        elif depth == 0 and (c == ";" or command.startswith("&&", i)):
            out.append("".join(cur).strip())
            cur = []
            i += 1 if c == ";" else 2
            continue
        cur.append(c)
        i += 1
    out.append("".join(cur).strip())
    return [s for s in out if s]


def plan(case: Case) -> tuple[list[str], str]:
    """(setup segments, the measured segment: the last one that runs semmap)."""
    segs = split_segments(case.command)
    idx = max((i for i, s in enumerate(segs) if SEMMAP in s), default=len(segs) - 1)
    return segs[:idx], segs[idx]


def expand(segment: str, root: Path) -> list[str]:
    """The words of ``segment`` after bash expansion (run from ``root``; ``$'..'``, ``$(..)`` and braces)."""
    segment = re.sub(r"\s\d?>&?\s*\S+", " ", segment)  # redirections: the words only
    proc = subprocess.run(["bash", "-c", f"printf '%s\\0' {segment}"], cwd=root, capture_output=True)
    return [w.decode("utf-8", "surrogateescape") for w in proc.stdout.split(b"\0")[:-1]]


def paths_of(words: list[str]) -> tuple[list[str], list[str]]:
    """(input paths, output paths) named by a command's words."""
    inputs, outputs, after_output = [], [], False
    for w in words:
        if after_output:
            outputs.append(w)
            after_output = False
            continue
        if w in OUTPUT_OPTIONS:
            after_output = True
            continue
        if w.startswith("--") and "=" in w:
            key, w = w.split("=", 1)
            if key in OUTPUT_OPTIONS:
                outputs.append(w)
                continue
        elif "=" in w and re.match(r"^[A-Z_][A-Z0-9_]*=", w):
            w = w.split("=", 1)[1]
        if not w or w.startswith("-") or w.endswith(SEMMAP) or w in ("./capped.sh", "/"):
            continue  # (an empty word, ``--dynamic ''``, is no path: it would name the scratch folder itself)
        inputs.append(w)
    return inputs, outputs


# ------------------------------------------------------------------------------------------------ fingerprints
def file_digest(path: str) -> str:
    """sha256 of a regular file (size + first and last MiB for files over 64 MiB: sparse 1 GiB fixtures); the
    file type for anything else (a device stays a device, a FIFO is never opened)."""
    try:
        st = os.lstat(path)
    except OSError:
        return "missing"
    if stat.S_ISLNK(st.st_mode):
        return "link:" + os.readlink(path)
    if not stat.S_ISREG(st.st_mode):
        return f"type:{stat.S_IFMT(st.st_mode):o}"
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            if st.st_size > BIG_FILE:
                h.update(f.read(2**20))
                f.seek(st.st_size - 2**20)
                h.update(f.read())
                return f"big:{st.st_size}:{h.hexdigest()}"
            for chunk in iter(lambda: f.read(2**20), b""):
                h.update(chunk)
    except OSError as exc:
        return f"unreadable:{exc.errno}"
    return h.hexdigest()


def fingerprint(path: str, *, deep: bool) -> dict[str, str]:
    """{relative path: digest} of a file or a folder tree (only the file type when not ``deep``)."""
    if not os.path.lexists(path):
        return {}
    if not deep or os.path.islink(path) or not os.path.isdir(path):
        return {".": file_digest(path) if deep else f"type:{stat.S_IFMT(os.lstat(path).st_mode):o}"}
    out = {".": "dir"}
    for dirpath, dirnames, filenames in os.walk(path):
        dirnames[:] = sorted(d for d in dirnames if not (dirpath == path and d == "h" and path.endswith("outputs")))
        for name in sorted(filenames) + [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]:
            full = os.path.join(dirpath, name)
            out[os.path.relpath(full, path)] = file_digest(full)
        for d in dirnames:
            out.setdefault(os.path.relpath(os.path.join(dirpath, d), path), "dir")
    return out


def watched(root: Path, words: list[str]) -> dict[str, bool]:
    """{path: deep} to fingerprint: inputs inside the scratch folder (deep), special files anywhere and outputs
    that exist (file type only: a device or a folder must not become a file)."""
    inputs, outputs = paths_of(words)
    out: dict[str, bool] = {}
    for w in inputs:
        p = w if os.path.isabs(w) else str(root / w)
        if not os.path.lexists(p):
            continue
        inside = os.path.realpath(p).startswith(str(root) + os.sep) or not os.path.isabs(w)
        if inside:
            out[w] = True
        elif not stat.S_ISREG(os.stat(p).st_mode) and not stat.S_ISDIR(os.stat(p).st_mode):
            out[w] = False
    for w in outputs:
        p = w if os.path.isabs(w) else str(root / w)
        if os.path.lexists(p) and w not in out:
            out[w] = False
    return out


def snapshot(root: Path, paths: dict[str, bool]) -> dict[str, dict[str, str]]:
    return {w: fingerprint(w if os.path.isabs(w) else str(root / w), deep=deep) for w, deep in paths.items()}


def changes(before: dict, after: dict) -> list[str]:
    out = []
    for w, old in before.items():
        new = after.get(w, {})
        diff = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
        if diff:
            out.append(w if diff == ["."] else f"{w} ({', '.join(diff[:3])}{', ...' if len(diff) > 3 else ''})")
    return out


# ------------------------------------------------------------------------------------------------ running
def timeout_of(case: Case, default: float) -> float:
    """The probe's own time-out for a case that hung (its seconds), else ``default``."""
    return max(case.seconds, default) if case.rc == 124 else default


def group_rss_mb(pgid: int) -> int:
    """Resident memory of every process in process group ``pgid`` (MiB), from /proc."""
    total = 0
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:
            total += int(fields[21]) * PAGE
    return total // 2**20


def run_segment(segment: str, root: Path, log: Path, timeout: float, mem_gb: float,
                interrupt_after: float | None = None) -> tuple[int, float, int, str]:
    """Run one bash segment in its own process group: (exit code, seconds, peak RSS MiB, '' or why it was
    killed: 'timeout' / 'memory'). A watchdog kills the group above ``mem_gb`` GiB resident (0: no watchdog);
    ``interrupt_after`` seconds in, the group gets SIGINT (Ctrl-C) once."""
    env = dict(os.environ, COLUMNS="120", PYTHONUNBUFFERED="1")
    with open(log, "wb") as out:
        start = time.monotonic()
        proc = subprocess.Popen(["bash", "-c", segment], cwd=root, stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True, env=env)
        killed, status, usage, tick = "", None, None, 0
        while status is None:
            pid, st, ru = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                status, usage = st, ru
                break
            tick += 1
            if interrupt_after is not None and time.monotonic() - start > interrupt_after:
                _kill_group(proc.pid, signal.SIGINT)
                interrupt_after = None
            if not killed and time.monotonic() - start > timeout:
                killed = "timeout"
                _kill_group(proc.pid, signal.SIGTERM)
                time.sleep(3)
                _kill_group(proc.pid, signal.SIGKILL)
            elif not killed and mem_gb > 0 and tick % 10 == 0 and group_rss_mb(proc.pid) > mem_gb * 1024:
                killed = "memory"
                _kill_group(proc.pid, signal.SIGKILL)
            time.sleep(0.05)
        seconds = time.monotonic() - start
    _kill_group(proc.pid, signal.SIGKILL)  # leftovers (Ray workers, a viewer)
    proc.returncode = os.waitstatus_to_exitcode(status)
    rc = proc.returncode if proc.returncode >= 0 else 128 - proc.returncode
    return rc, seconds, usage.ru_maxrss // 1024, killed


def _kill_group(pgid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, sig)


def prepare(setup: list[str], root: Path) -> None:
    """Run a case's setup segments (``cp -r SRC DST`` gets a fresh DST: a copy from an earlier run is removed)."""
    for seg in setup:
        words = expand(seg, root) if seg.startswith("cp ") else []
        if len(words) >= 4 and words[1] == "-r":
            dst = root / words[-1]
            if dst.is_dir() and not dst.is_symlink() and str(dst.resolve()).startswith(str(root)):
                shutil.rmtree(dst, ignore_errors=True)
    if setup:
        subprocess.run(["bash", "-c", "; ".join(setup)], cwd=root, capture_output=True, timeout=300)


def missing_fixture(case: Case, words: list[str], root: Path, not_built: dict[str, str]) -> str:
    """Why a case cannot be reproduced here ('' when it can)."""
    for fixture, why in not_built.items():
        if re.search(rf"(^|[\s=']){re.escape(fixture)}(/|\s|$|')", case.command):
            return f"fixture {fixture} not built: {why}"
    if words and words[0] == "setpriv" and not shutil.which("setpriv"):
        return "setpriv is not installed"
    return ""


def run_case(case: Case, root: Path, logs: Path, args, not_built: dict[str, str]) -> Result:
    setup, segment = plan(case)
    res = Result(case.id, "GOOD", case.original_class(), command=case.command)
    if args.skip and re.search(args.skip, case.id):
        res.cls, res.reason = "SKIPPED", "--skip"
        return res
    top = root
    if setup and setup[-1].startswith("cd "):  # ``cd o && ../.venv/bin/semmap ...``: the command runs in o/
        root, setup = root / setup[-1][3:].strip(), setup[:-1]
    prepare(setup, top)
    words = expand(segment, root)
    why = missing_fixture(case, words, root, not_built)
    if not why and case.probe_class and (unmade := surfaces.unbuilt(case.command, args.fixtures)):
        why = f"no fixture in scripts/probes/surfaces.py makes {', '.join(unmade[:3])}"
    if why:
        res.cls, res.reason = "NOT-REPRODUCED", why
        return res
    paths = watched(root, words)
    before = snapshot(root, paths)
    log = logs / f"{re.sub(r'[^A-Za-z0-9_.#-]', '_', case.id)}.out"
    res.rc, res.seconds, res.peak_mb, killed = run_segment(segment, root, log, timeout_of(case, args.timeout),
                                                           args.max_memory_gb, surfaces.INTERRUPTS.get(case.name))
    res.changed = changes(before, snapshot(root, paths))
    text = ANSI.sub("", log.read_bytes().decode("utf-8", "replace")).replace("\r", "\n")
    if killed == "memory":
        res.peak_mb = max(res.peak_mb, int(args.max_memory_gb * 1024))
        text += f"\n[killed by the harness above {args.max_memory_gb} GB]\n"
    res.cls, res.reason = classify(res.rc, res.peak_mb, killed == "timeout", res.changed, text, names_of(words))
    if res.cls == "GOOD" and case.probe_class == "SILENT-WRONG" and not surfaces.silent_fixed(case.name, res.rc, text):
        res.cls, res.reason = "SILENT-WRONG", "exit 0 without a warning, as in the probe"
    res.excerpt = " | ".join(x.strip() for x in text.splitlines() if x.strip() and not PROGRESS.search(x))[-600:]
    return res


def names_of(words: list[str]) -> set[str]:
    """What a good error line may name: the command's paths, options and environment variables."""
    out = set()
    for w in words:
        if w.endswith(SEMMAP) or w == "./capped.sh":
            continue
        if re.match(r"^[A-Z_][A-Z0-9_]*=", w):
            out |= set(w.split("=", 1))
        elif w.startswith("--"):
            opt = w.split("=", 1)[0]
            out |= {opt, opt[2:], opt[2:].replace("-", "_")}  # 'invalid option input_size: ...' names it too
        elif "/" in w or "." in w:
            out.add(w)
            if re.match(r"^[a-z]+:[^/]", w):  # ``onnx:MODEL``: the model's path is named alone
                out.add(w.split(":", 1)[1])
    return out


def classify(rc: int, peak_mb: int, timed_out: bool, changed: list[str], text: str,
             names: set[str] | None = None) -> tuple[str, str]:
    """(class, reason) of one finished case; ``names``: what its error line should name (NO-NAME otherwise)."""
    if changed:
        return "DATA-LOSS", "changed: " + "; ".join(changed)
    if rc in (139, 134) or "Segmentation fault" in text or "Fatal Python error" in text:
        return "SEGFAULT", f"rc {rc}"
    if "Traceback (most recent call last)" in text:
        return "TRACEBACK", text[text.rindex("Traceback"):].strip().splitlines()[-1][:200]
    if timed_out:
        return "HANG", f"killed after the time-out ({peak_mb} MB)"
    memory_words = ("killed by the harness above", "MemoryError", "bad_alloc")
    if rc == 137 or any(w in text for w in memory_words) or (rc != 0 and peak_mb > MEMORY_MB):
        return "MEMORY", f"rc {rc}, peak {peak_mb} MB"
    if rc == 130 and "interrupted" not in text:
        return "UNCLEAR", "Ctrl-C: exit 130 without a word"
    if rc in (0, 130):
        return "GOOD", ""
    if rc in (126, 127) and "semmap" not in text.replace(".venv/bin/semmap", ""):
        return "INVALID", f"rc {rc}: the command could not start (as in the probe's uid-65534 rows)"
    lines = [x.strip() for x in text.splitlines() if x.strip() and not PROGRESS.search(x)]
    if rc == 2 and ("Usage:" in text or "usage:" in text or "Invalid value" in text or "No such option" in text):
        return "GOOD", "usage error (the option is named)"  # click's or argparse's: a missing option is named
    first = next((i for i, x in enumerate(lines) if ERROR_LINE.match(x)), None)
    if first is None:
        return "UNCLEAR", f"rc {rc} without a 'semmap: error:' line"
    extra = [x for x in lines[first + 1:] if not re.match(r"semmap: (WARNING|INFO)", x)]
    if extra:
        return "MULTI-LINE", f"{len(extra)} more line(s) after the error: {extra[0][:120]}"
    if names and not any(re.search(rf"(?<![\w-]){re.escape(n)}(?![\w-])", lines[first]) for n in names):
        return "NO-NAME", "the error names no file or option of the command"
    return "GOOD", ""


# ------------------------------------------------------------------------------------------------ scheduling
def serial_ids(cases: list[Case], root: Path) -> set[str]:
    """Cases that must not run beside another: setup steps, full/ and ro/, outputs outside outputs/h, output
    paths shared by several cases (locks, resumes), inputs that are an earlier case's output, ./capped.sh."""
    counts: dict[str, int] = {}
    outs: dict[str, list[str]] = {}
    reads_outputs: set[str] = set()
    for c in cases:
        _, seg = plan(c)
        ins, outs[c.id] = paths_of(seg.split())
        if any(w.startswith("outputs/h/") for w in ins):
            reads_outputs.add(c.id)  # an earlier case's output: run after the parallel ones
        for o in outs[c.id]:
            counts[o] = counts.get(o, 0) + 1
    serial = set()
    for c in cases:
        setup, seg = plan(c)
        shared = any(counts[o] > 1 for o in outs[c.id])
        foreign = any(not o.startswith("outputs/h/") for o in outs[c.id])
        mounts = re.search(r"(^|\s)(full/|ro/|outputs(\s|$))", seg)
        if setup or shared or foreign or mounts or c.id in reads_outputs or "capped" in seg or c.probe_class:
            serial.add(c.id)  # (the new-surfaces probe ran its cases one at a time, in order: o/ is shared)
    return serial


def run_all(cases: list[Case], root: Path, out: Path, args) -> list[Result]:
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    info = root / "FIXTURES.json"
    not_built = json.loads(info.read_text())["not_built"] if info.exists() else {}
    if not args.keep_outputs:
        shutil.rmtree(root / "outputs" / "h", ignore_errors=True)
    (root / "outputs" / "h").mkdir(parents=True, exist_ok=True)
    serial = serial_ids(cases, root)
    results: dict[str, Result] = {}

    def one(c: Case) -> None:
        r = run_case(c, root, logs, args, not_built)
        results[c.id] = r
        print(f"{len(results):4d}/{len(cases)} {r.cls:14s} {r.seconds:6.1f}s {r.peak_mb:6d}MB {c.id}", flush=True)

    parallel = [c for c in cases if c.id not in serial]
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        list(pool.map(one, parallel))
    for c in cases:
        if c.id in serial:
            one(c)
    return [results[c.id] for c in cases]


# ------------------------------------------------------------------------------------------------ reports
def write_reports(results: list[Result], out: Path, wall: float) -> None:
    cols = ["id", "cls", "original", "rc", "seconds", "peak_mb", "reason", "changed", "command", "excerpt"]
    with open(out / "results.tsv", "w", encoding="utf-8", errors="surrogateescape") as f:
        f.write("\t".join(cols) + "\n")
        for r in results:
            d = asdict(r)
            d["changed"] = "; ".join(r.changed)
            f.write("\t".join(str(d[c]).replace("\t", " ").replace("\n", " ") for c in cols) + "\n")
    counts = {c: sum(r.cls == c for r in results) for c in CLASSES}
    same = sum(r.cls == r.original or {r.cls, r.original} <= UNCLEAR_FAMILY for r in results)
    when = f"in {wall / 60:.1f} min" if wall else "classified again"
    lines = [f"# Probe re-run ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())})", "",
             f"{len(results)} cases {when}; the class equals the probe's for {same}.", "",
             "NO-NAME, MULTI-LINE and UNCLEAR all count as the probe's UNCLEAR. The probe's class comes from its rc,",
             "traceback flag and peak memory, and from the report for DATA-LOSS and UNCLEAR; its SILENT-WRONG cases",
             "show as GOOD here.", "",
             "| class | cases |", "|---|---|"]
    lines += [f"| {c} | {n} |" for c, n in counts.items() if n]
    moved = {}
    for r in results:
        moved[(r.original, r.cls)] = moved.get((r.original, r.cls), 0) + 1
    lines += ["", "## Probe's class -> now", "", "| probe | now | cases |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {n} |" for (a, b), n in sorted(moved.items())]
    lines += ["", "## Cases that are not GOOD", ""]
    for r in results:
        if r.cls != "GOOD":
            lines += [f"### {r.id}: {r.cls} (probe: {r.original})", "", f"`{r.command}`", "",
                      f"rc {r.rc}, {r.seconds:.1f} s, {r.peak_mb} MB. {r.reason}", "",
                      "```", r.excerpt[-400:], "```", ""]
    (out / "summary.md").write_text("\n".join(lines), encoding="utf-8", errors="surrogateescape")


def reclassify(out: Path, cases: list[Case], root: Path) -> list[Result]:
    """The results of an earlier run (RESULTS/results.tsv and logs/) classified again with this code."""
    by_id = {c.id: c for c in cases}
    results = []
    with open(out / "results.tsv", encoding="utf-8", errors="surrogateescape") as f:
        cols = f.readline().rstrip("\n").split("\t")
        for line in f:
            d = dict(zip(cols, line.rstrip("\n").split("\t"), strict=True))
            case = by_id.get(d["id"])
            log = out / "logs" / f"{re.sub(r'[^A-Za-z0-9_.#-]', '_', d['id'])}.out"
            if case is None or not log.exists() or d["rc"] == "None":
                continue
            r = Result(d["id"], d["cls"], case.original_class(), int(d["rc"]), float(d["seconds"]),
                       int(d["peak_mb"]), d["reason"], [x for x in d["changed"].split("; ") if x], case.command,
                       d["excerpt"])
            text = ANSI.sub("", log.read_bytes().decode("utf-8", "replace")).replace("\r", "\n")
            timed_out = r.cls == "HANG"
            r.cls, r.reason = classify(r.rc, r.peak_mb, timed_out, r.changed, text,
                                       names_of(expand(plan(case)[1], root)))
            if r.cls == "GOOD" and case.probe_class == "SILENT-WRONG" and not surfaces.silent_fixed(case.name, r.rc,
                                                                                                   text):
                r.cls, r.reason = "SILENT-WRONG", "exit 0 without a warning, as in the probe"
            results.append(r)
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dir", type=Path, help="scratch folder built by build_fixtures.py")
    ap.add_argument("--cases", help="run only cases whose name matches this regex")
    ap.add_argument("--skip", help="mark cases whose name matches this regex SKIPPED")
    ap.add_argument("--jobs", type=int, default=1, help="cases at a time (cases that share state run alone)")
    ap.add_argument("--out", type=Path, default=Path("probe-results"), help="results folder")
    ap.add_argument("--tsv", type=Path, help="the probe's case table (default: the --probe's)")
    ap.add_argument("--probe", choices=("bad-input", "new-surfaces"), default="bad-input",
                    help="the bad-input probe of 2026-11-25 or the new-surfaces one of 2026-11-28")
    ap.add_argument("--timeout", type=float, default=120, help="seconds per case (a case that hung in the probe "
                    "keeps its longer time-out)")
    ap.add_argument("--max-memory-gb", type=float, default=8, help="kill a case whose processes hold more than this "
                    "resident, to protect the machine (0 = never); it is then MEMORY")
    ap.add_argument("--keep-outputs", action="store_true", help="keep DIR/outputs/h from an earlier run")
    ap.add_argument("--reclassify", action="store_true", help="classify the results in --out again (no run)")
    args = ap.parse_args()
    root = args.dir.resolve()
    tsv = args.tsv or (surfaces.TSV if args.probe == "new-surfaces" else TSV)
    import build_fixtures

    args.fixtures = set(build_fixtures.tables(args.probe)[0])
    cases = [c for c in read_cases(tsv) if not args.cases or re.search(args.cases, c.id)]
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    results = reclassify(args.out, cases, root) if args.reclassify else run_all(cases, root, args.out, args)
    write_reports(results, args.out, 0.0 if args.reclassify else time.monotonic() - start)
    bad = [r for r in results if r.cls != "GOOD"]
    print(f"{len(results)} cases, {len(bad)} not GOOD; {args.out / 'summary.md'}")
    sys.exit(0)


if __name__ == "__main__":
    main()
