"""Hostile files for the reader tests: each case is (reader, path) with the problem it carries. Also runnable as a
script (``python tests/hostile.py FOLDER``): builds the cases, reads each, prints one JSON line with every outcome
and the process's peak RSS, so the test can check memory stays bounded."""

from __future__ import annotations

import json
import os
import resource
import struct
import sys
import zipfile
from pathlib import Path

import numpy as np

#: Peak memory a reader may reach on any hostile file (the issue's bound), in MiB.
MAX_RSS_MB = 300
SPARSE_BYTES = 2**30


def _npy_member(z: zipfile.ZipFile, name: str, header: dict, data: bytes = b"") -> None:
    with z.open(f"{name}.npy", "w") as f:
        np.lib.format.write_array_header_1_0(f, header)
        f.write(data)


def _semmap_with(path: Path, header_json: object | None = None, arrays: dict | None = None) -> Path:
    """A .semmap-shaped zip: the given JSON header and arrays (all other arrays empty and well-formed)."""
    from semmap.io.native import _ARRAYS, FORMAT, VERSION

    header = header_json if header_json is not None else {
        "format": FORMAT, "version": VERSION, "resolution": 0.1, "max_range": -1.0,
        "occupancy": {}, "semantics": {}, "label_set": None}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        text = json.dumps(header).encode()
        _npy_member(z, "header", {"descr": "|u1", "fortran_order": False, "shape": (len(text),)}, text)
        for name, (dtype, tail) in _ARRAYS.items():
            if arrays and name in arrays:
                arrays[name](z, name)
                continue
            shape = (0, *(3 if t == "k" else t for t in tail))
            _npy_member(z, name, {"descr": np.dtype(dtype).str, "fortran_order": False, "shape": shape})
    return path


def _huge_array(z: zipfile.ZipFile, name: str) -> None:
    """An array member whose .npy header claims 10^12 elements but holds 8 bytes."""
    _npy_member(z, name, {"descr": "<i8", "fortran_order": False, "shape": (10**12,)}, b"\0" * 8)


def _bomb(z: zipfile.ZipFile, name: str) -> None:
    """An array member of 256 MiB of zeros: a few hundred KiB compressed."""
    with z.open(f"{name}.npy", "w", force_zip64=True) as f:
        np.lib.format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False, "shape": (2**26,)})
        chunk = b"\0" * 2**22
        for _ in range(2**28 // len(chunk)):
            f.write(chunk)


def _ot_header(size: int, tree: str = "ColorOcTree") -> bytes:
    return f"# Octomap OcTree file\nid {tree}\nsize {size}\nres 0.1\ndata\n".encode()


def build_cases(root: Path) -> dict[str, tuple[str, Path]]:
    """{case: (reader, path)}; readers name the file kinds read below."""
    root.mkdir(parents=True, exist_ok=True)
    cases: dict[str, tuple[str, Path]] = {}

    def put(name: str, reader: str, path: Path) -> None:
        cases[name] = (reader, path)

    (root / "huge_count.ot").write_bytes(_ot_header(10**11) + b"\0" * 64)
    put("ot header claims 10^11 nodes", "octomap", root / "huge_count.ot")
    (root / "huge_count.bt").write_bytes(b"# Octomap OcTree binary file\nid OcTree\nsize 100000000000\nres 0.1\n"
                                         b"data\n" + b"\xff" * 64)
    put("bt header claims 10^11 nodes", "octomap", root / "huge_count.bt")
    record = struct.pack("<f", float("nan")) + b"\0"  # one OcTree leaf of NaN log-odds
    (root / "nan.ot").write_bytes(_ot_header(1, "OcTree") + record)
    put("ot leaf with NaN log-odds", "octomap", root / "nan.ot")
    put("semmap array claims 10^12 elements", "semmap",
        _semmap_with(root / "huge_array.semmap", arrays={"packed": _huge_array}))
    put("semmap zip bomb", "semmap", _semmap_with(root / "bomb.semmap", arrays={"logodds": _bomb}))
    put("semmap header is a JSON list", "semmap", _semmap_with(root / "list.semmap", header_json=[1, 2, 3]))
    from semmap.io.native import FORMAT, VERSION

    bad_types = {"format": FORMAT, "version": VERSION, "resolution": "fine", "max_range": -1, "occupancy": {},
                 "semantics": {}, "label_set": None}
    put("semmap resolution is a string", "semmap", _semmap_with(root / "string.semmap", header_json=bad_types))
    bad_k = {**bad_types, "resolution": 0.1, "semantics": {"k": 2.5}}
    put("semmap k is not whole", "semmap", _semmap_with(root / "k.semmap", header_json=bad_k))
    bad_labels = {**bad_types, "resolution": 0.1, "label_set": {"classes": "all"}}
    put("semmap label set malformed", "semmap", _semmap_with(root / "labels.semmap", header_json=bad_labels))
    for suffix, reader in ((".ot", "octomap"), (".semmap", "semmap"), (".ply", "ply"), (".txt", "trajectory"),
                           (".bag", "rosbag")):
        sparse = root / f"sparse{suffix}"
        with open(sparse, "wb") as f:
            f.truncate(SPARSE_BYTES)
        put(f"1 GiB sparse file {sparse.name}", reader, sparse)
        zero = root / f"zero{suffix}"
        if not zero.exists():
            zero.symlink_to("/dev/zero")
        put(f"/dev/zero named {zero.name}", reader, zero)
        fifo = root / f"fifo{suffix}"
        if not fifo.exists():
            os.mkfifo(fifo)
        put(f"FIFO named {fifo.name}", reader, fifo)
    seq = root / "tum_fifo"
    seq.mkdir(exist_ok=True)
    if not (seq / "rgb.txt").exists():
        os.mkfifo(seq / "rgb.txt")
    (seq / "depth.txt").write_text("0 depth/0.png\n")
    put("TUM rgb.txt is a FIFO", "dataset", seq)
    return cases


def _read(reader: str, path: Path) -> None:
    if reader == "octomap":
        from semmap.io.octomap_files import read_octomap

        read_octomap(path)
    elif reader == "semmap":
        from semmap.io.map_info import describe_map_file

        describe_map_file(path)
    elif reader == "ply":
        from semmap.io.ply import read_ply

        read_ply(path)
    elif reader == "trajectory":
        from semmap.io.trajectory import read_trajectory

        read_trajectory(path, strict=True)
        read_trajectory(path)
    else:
        from semmap.datasets import open_dataset

        for _ in open_dataset(path):
            pass


def _warm_up(folder: Path) -> None:
    """Read one valid file of each kind first, so numba's one-time kernel compilation (hundreds of MB of LLVM work
    on a cold cache) is not counted as memory spent on a hostile file."""
    import importlib.util

    script = Path(__file__).resolve().parents[1] / "scripts" / "fuzz_readers.py"
    spec = importlib.util.spec_from_file_location("_fuzz_readers", script)
    fuzz = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fuzz)
    for name, data in fuzz.seed_files(folder / "warm-up").items():
        fuzz.TARGETS[name](data, folder / "warm-up")


def _reset_peak_rss() -> bool:
    """Reset the kernel's peak-RSS mark (Linux: ``5 > /proc/self/clear_refs``); False where that is refused."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _peak_rss_mb(reset: bool) -> float:
    if reset:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(folder: str) -> None:
    import logging

    from semmap.errors import SemmapError

    logging.getLogger("semmap").setLevel(logging.CRITICAL)
    cases = build_cases(Path(folder))
    _warm_up(Path(folder))
    reset = _reset_peak_rss()
    outcomes = {}
    for name, (reader, path) in cases.items():
        try:
            _read(reader, path)
            outcomes[name] = "read without error"
        except SemmapError as exc:
            outcomes[name] = f"SemmapError: {exc}"
        except Exception as exc:
            outcomes[name] = f"{type(exc).__name__}: {exc}"
    print(json.dumps({"outcomes": outcomes, "peak_rss_mb": round(_peak_rss_mb(reset), 1),
                      "peak_since_warm_up": reset}))


if __name__ == "__main__":
    main(sys.argv[1])
