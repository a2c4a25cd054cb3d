"""The fixture table of build_fixtures.py: every path the probe's commands name -> how to build it. The hand-made
fixtures are inferred from their names, the commands and the outputs recorded in the probe's TSV."""

from __future__ import annotations

import copy as copy_module
import json
import os
import shutil
import subprocess
import zipfile
from functools import partial
from pathlib import Path

import cv2
import fixtures_lib as fx
import numpy as np

#: Fixtures rebuilt on every build: victims that a case may overwrite, and the mounts.
ALWAYS = {".venv/bin/semmap", "ro", "full", "h/victim.ot", "h/victim_in", "h/v2", "h/v3", "h/evs2", "h/perm"}
#: Fixtures this harness does not rebuild, and why (the cases that need them come out NOT-REPRODUCED).
NOT_REPRODUCIBLE: dict[str, str] = {}


def remove(path: Path) -> None:
    """Remove a fixture of any kind (a mount point is unmounted first; read-only modes are lifted)."""
    if os.path.ismount(path):
        subprocess.run(["umount", str(path)], check=False)
    if not os.path.lexists(path):
        return
    if path.is_dir() and not path.is_symlink():
        for dirpath, dirnames, _ in os.walk(path):
            for d in dirnames:
                p = Path(dirpath, d)
                if not p.is_symlink():
                    p.chmod(0o755)
        path.chmod(0o755)
        shutil.rmtree(path)
    else:
        path.unlink()


# ------------------------------------------------------------------------------------------------ builders
def copy(src: str, ctx, path: Path) -> None:
    s = ctx.p(src)
    (fx.copytree if s.is_dir() else lambda a, b: (b.parent.mkdir(parents=True, exist_ok=True), shutil.copy2(a, b)))(
        s, path)


def data(content: bytes | str, _ctx, path: Path) -> None:
    fx.write(path, content)


def garbage(_ctx, path: Path, n: int = 4096) -> None:
    fx.write(path, fx.noise(path.name, n))


def trunc(src: str, keep, ctx, path: Path) -> None:
    fx.truncated(ctx.p(src), path, keep)


def special(kind: str, _ctx, path: Path) -> None:
    {"zero": fx.char_device, "null": partial(fx.char_device, minor=3), "fifo": fx.fifo, "sparse": fx.sparse,
     "loop": fx.symlink_loop, "dir": lambda p: p.mkdir(parents=True)}[kind](path)


def octomap(src: str, ctx, path: Path, **kw) -> None:
    fx.octomap_with(ctx.p(src), path, **kw)


def small_octomap(res: str, ctx, path: Path, size: str = "1000") -> None:
    """An .ot with ``size`` 1000 and resolution ``res`` over the good map's tree data."""
    fx.octomap_with(ctx.p("outputs/office/map.ot"), path, size=size, res=res)


def octomap_text(header: str, ctx, path: Path) -> None:
    fx.write(path, header.encode())


def sem(src: str, edit, ctx, path: Path) -> None:
    fx.semmap_variant(ctx.p(src), path, edit)


def sem_raw(header, ctx, path: Path, drop: str | None = None) -> None:
    """A .semmap with header ``header`` (any JSON) over the good map's arrays, or without member ``drop``."""
    h, arrays = fx.read_semmap(ctx.p("outputs/office/map.semmap"))
    if drop == "header":
        fx.write_semmap(path, None, arrays, with_header=False)
        return
    if drop:
        arrays.pop(drop)
    fx.write_semmap(path, h if header is ... else header, arrays)


def _set(key, value):
    def edit(h, a):
        h[key] = value
    return edit


def _arr(name, fn):
    def edit(h, a):
        a[name] = fn(a[name])
    return edit


def _many_classes(h, a):
    h["label_set"] = {"classes": [{"id": i, "name": f"c{i}", "color": [0, 0, 0]} for i in range(70000)]}


def semmap_bomb(_ctx, path: Path) -> None:
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
    import hostile
    hostile._semmap_with(path, arrays={"logodds": hostile._bomb})


def ply(edit, ctx, path: Path) -> None:
    fx.ply_header_edit(ctx.p("outputs/maps3/voxelgrid.ply"), path, edit)


def _replace(old: str, new: str):
    return lambda lines: [new if line.startswith(old) else line for line in lines]


def ply_vertex_count(count: str):
    return _replace("element vertex", f"element vertex {count}")


def ply_nan(ctx, path: Path) -> None:
    lines, v = fx.ply_vertices(ctx.p("outputs/maps3/voxelgrid.ply"))
    v["x"] = np.nan
    v["label"] = 60000
    fx.write(path, fx.ply_from(lines, v.tobytes()))


def ply_xyz(scale: float, ctx, path: Path) -> None:
    _, v = fx.ply_vertices(ctx.p("outputs/maps3/voxelgrid.ply"))
    fx.ply_xyz(path, np.stack([v["x"], v["y"], v["z"]], 1) * scale)


def ply_zero(ctx, path: Path) -> None:
    lines, _ = fx.split_ply(ctx.p("outputs/maps3/voxelgrid.ply").read_bytes())
    fx.write(path, fx.ply_from(ply_vertex_count("0")(lines), b""))


def ply_hugecount(ctx, path: Path) -> None:
    lines, body = fx.split_ply(ctx.p("outputs/maps3/voxelgrid.ply").read_bytes())
    fx.write(path, fx.ply_from(ply_vertex_count("1000000000000")(lines), body[:1000]))


def long_path(ctx, path: Path) -> None:
    deep = path
    for c in "defghi":
        deep = deep / (c * 200)
    deep.mkdir(parents=True)
    shutil.copy2(ctx.p("outputs/office/map.ot"), deep / "map.ot")


# ------------------------------------------------------------------------------------------------ sequences
def tum(edit, ctx, path: Path, src: str = "sim/tiny") -> None:
    """A copy of a TUM sequence (sim/tiny) with ``edit(folder)`` applied."""
    fx.copytree(ctx.p(src), path)
    edit(path)


def pngs(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.png"))


def each_png(sub: str, fn, flags=cv2.IMREAD_UNCHANGED):
    """Rewrite every PNG of ``sub``/ as ``fn(image)``."""
    def edit(seq: Path) -> None:
        for p in pngs(seq / sub):
            cv2.imwrite(str(p), fn(cv2.imread(str(p), flags)))
    return edit


def each_file(sub: str, fn):
    def edit(seq: Path) -> None:
        for p in pngs(seq / sub):
            fn(p)
    return edit


def put(name: str, content: bytes | str):
    return lambda seq: fx.write(seq / name, content)


def json_edit(name: str, fn):
    def edit(seq: Path) -> None:
        doc = json.loads((seq / name).read_text())
        (seq / name).write_text(json.dumps(fn(doc)))
    return edit


def _cam(**fields):
    return json_edit("camera.json", lambda d: {**d, **fields})


def gt_edit(fn):
    """groundtruth.txt rows (t tx ty tz qx qy qz qw) passed through ``fn(array) -> array or text``."""
    def edit(seq: Path) -> None:
        rows = np.loadtxt(seq / "groundtruth.txt", ndmin=2)
        out = fn(rows)
        fx.write(seq / "groundtruth.txt", out if isinstance(out, str) else
                 "\n".join(" ".join(repr(float(x)) for x in r) for r in out) + "\n")
    return edit


def _cols(rows, **cols):
    rows = rows.copy()
    for i, v in cols.items():
        rows[:, int(i[1:])] = v
    return rows


def list_edit(name: str, fn):
    """Rewrite the data rows (non-comment lines) of rgb.txt / depth.txt with ``fn(lines) -> lines``."""
    def edit(seq: Path) -> None:
        lines = [x for x in (seq / name).read_text().splitlines() if x and not x.startswith("#")]
        fx.write(seq / name, "\n".join(fn(lines)) + "\n")
    return edit


def rm(*names: str):
    def edit(seq: Path) -> None:
        for n in names:
            for p in sorted(seq.glob(n)):
                remove(p)
    return edit


def chain(*edits):
    def edit(seq: Path) -> None:
        for e in edits:
            e(seq)
    return edit


def static_seq(ctx, path: Path) -> None:
    """10 identical frames of sim/tiny's first frame, ground truth constant (a camera that does not move)."""
    src = ctx.p("sim/tiny")
    fx.copytree(src, path)
    for sub in ("rgb", "depth", "labels", "instances"):
        first = pngs(src / sub)[0]
        for p in pngs(path / sub):
            p.unlink()
        for i in range(10):
            shutil.copy2(first, path / sub / f"{i / 30:.6f}.png")
    pose = np.loadtxt(src / "groundtruth.txt", ndmin=2)[0, 1:]
    for name, sub in (("rgb.txt", "rgb"), ("depth.txt", "depth")):
        fx.write(path / name, "".join(f"{i / 30:.6f} {sub}/{i / 30:.6f}.png\n" for i in range(10)))
    fx.write(path / "groundtruth.txt", "".join(f"{i / 30:.6f} " + " ".join(repr(float(x)) for x in pose) + "\n"
                                               for i in range(10)))


def huge_rgbtxt(seq: Path) -> None:
    first = (seq / "rgb.txt").read_text().splitlines()[2].split()[1]
    with open(seq / "rgb.txt", "w") as f:
        f.writelines(f"{i * 1e-6:.6f} {first}\n" for i in range(2_000_000))


def ls_classes(fn):
    return json_edit("labelset.json", lambda d: {"classes": fn(d["classes"])})


def _dup_ids(c):
    c[2]["id"] = 1
    return c


def _neg_id(c):
    c[1]["id"] = -1
    return c


def _name_types(c):
    c[0]["id"] = "zero"
    return c


def _color_oob(c):
    c[1]["color"] = [999, 0, 0]
    return c


TUM_VARIANTS = {
    "cam_garbage": put("camera.json", b"\xff" + fx.noise("cam", 200)),
    "cam_huge": _cam(width=100000, height=100000),
    "cam_list": put("camera.json", "[525, 525, 319.5, 239.5]"),
    "cam_nan": json_edit("camera.json", lambda d: {**d, "fx": float("nan")}),
    "cam_neg": json_edit("camera.json", lambda d: {**d, "fx": -d["fx"], "fy": -d["fy"]}),
    "cam_types": json_edit("camera.json", lambda d: {**d, "width": [d["width"]]}),
    "cam_wrongsize": json_edit("camera.json", lambda d: {**d, "width": d["width"] // 2, "height": d["height"] // 2}),
    "cam_zero_fx": _cam(fx=0.0, fy=0.0),
    "color_16bit": each_png("rgb", lambda im: im.astype(np.uint16) * 257),
    "color_gray": each_png("rgb", lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)),
    "color_rgba": each_png("rgb", lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2BGRA)),
    "color_small": each_png("rgb", lambda im: cv2.resize(im, (im.shape[1] // 2, im.shape[0] // 2))),
    "depth_8bit": each_png("depth", lambda im: np.clip(im // 32, 0, 255).astype(np.uint8)),
    "depth_bomb": lambda seq: fx.png_bomb(pngs(seq / "depth")[1]),
    "depth_metres": each_png("depth", lambda im: np.rint(im / 1000.0).astype(np.uint16)),
    "depth_small": each_png("depth", lambda im: cv2.resize(im, (im.shape[1] // 2, im.shape[0] // 2),
                                                          interpolation=cv2.INTER_NEAREST)),
    "dup_ts": chain(list_edit("rgb.txt", lambda x: [x[0], *x]), list_edit("depth.txt", lambda x: [x[0], *x])),
    "empty_rgbtxt": put("rgb.txt", ""),
    "garbage_depth": each_file("depth", lambda p: fx.write(p, fx.noise(p.name, 3000))),
    "garbage_rgbtxt": put("rgb.txt", b"\xff" + fx.noise("rgbtxt", 500)),
    "gt_1e300": gt_edit(lambda r: _cols(r, c1=1e300, c2=-1e300, c3=1e300)),
    "gt_1e6": gt_edit(lambda r: _cols(r, c1=1e6)),
    "gt_7cols": gt_edit(lambda r: r[:, :7]),
    "gt_empty": put("groundtruth.txt", ""),
    "gt_missing": rm("groundtruth.txt"),
    "gt_nan": gt_edit(lambda r: _cols(r, c1=np.nan, c2=np.nan, c3=np.nan)),
    "gt_unnorm": gt_edit(lambda r: np.hstack([r[:, :4], 2 * r[:, 4:]])),
    "gt_zeroquat": gt_edit(lambda r: _cols(r, c4=0, c5=0, c6=0, c7=0)),
    "gt_dup": gt_edit(lambda r: np.repeat(r, 2, axis=0)),
    "gt_unsorted": gt_edit(lambda r: r[::-1]),
    "img_devzero": list_edit("rgb.txt", lambda x: [x[0], x[1].split()[0] + " /dev/zero", *x[2:]]),
    "img_etc_passwd": list_edit("rgb.txt", lambda x: [x[0], x[1].split()[0] + " /etc/passwd", *x[2:]]),
    "label_garbage": each_file("labels", lambda p: fx.write(p, fx.noise(p.name, 3000))),
    "label_oob": each_png("labels", lambda im: np.where(np.arange(im.size).reshape(im.shape) == 0, 200, im)
                          .astype(im.dtype)),
    "label_rgb": each_png("labels", lambda im: cv2.cvtColor(im.astype(np.uint8), cv2.COLOR_GRAY2BGR)),
    "label_wrongsize": each_png("labels", lambda im: cv2.resize(im, (im.shape[1] // 2, im.shape[0] // 2),
                                                                interpolation=cv2.INTER_NEAREST)),
    "labels_16bit": each_png("labels", lambda im: im.astype(np.uint16) + 60000),
    "labels_empty": lambda seq: [p.unlink() for p in pngs(seq / "labels")],
    "ls_color_oob": ls_classes(_color_oob),
    "ls_dup_ids": ls_classes(_dup_ids),
    "ls_empty_classes": ls_classes(lambda c: []),
    "ls_few": ls_classes(lambda c: c[:2]),
    "ls_garbage": put("labelset.json", b"\xff" + fx.noise("ls", 300)),
    "ls_huge": ls_classes(lambda c: [{"id": i, "name": f"c{i}", "color": [0, 0, 0]} for i in range(70000)]),
    "ls_list": put("labelset.json", '["unknown", "wall", "floor"]'),
    "ls_name_types": ls_classes(_name_types),
    "ls_neg_id": ls_classes(_neg_id),
    "missing_depth_imgs": rm("depth/*.png"),
    "missing_imgs": rm("rgb/*.png"),
    "nonutf8": lambda seq: fx.write(seq / "rgb.txt", b"# colour imag\xff\n" + (seq / "rgb.txt").read_bytes()),
    "nul": lambda seq: fx.write(seq / "rgb.txt", (seq / "rgb.txt").read_bytes().replace(b" ", b"\0 ", 3)),
    "one_frame": list_edit("rgb.txt", lambda x: x[:1]),
    "png_bomb": lambda seq: fx.png_bomb(pngs(seq / "rgb")[1], bit_depth=8),
    "rgbtxt_devzero": lambda seq: (remove(seq / "rgb.txt"), fx.char_device(seq / "rgb.txt")),
    "rgbtxt_dir": lambda seq: (remove(seq / "rgb.txt"), (seq / "rgb.txt").mkdir()),
    "trunc_one_depth": lambda seq: fx.truncated(pngs(seq / "depth")[1], pngs(seq / "depth")[1], 0.5),
    "zero_depth": each_png("depth", lambda im: np.zeros_like(im)),
    "scene_garbage": put("scene.json", b"\x96" + fx.noise("scene", 300)),
    "scene_list": put("scene.json", "[1, 2, 3]"),
    "scene_missing": rm("scene.json"),
    "objects_garbage": put("objects.json", b"\x96" + fx.noise("objects", 300)),
    "depthtxt_garbage": put("depth.txt", "this is not a file list\n"),
    "instances_garbage": each_file("instances", lambda p: fx.write(p, fx.noise(p.name, 3000))),
    "huge_rgbtxt": huge_rgbtxt,
}


# ------------------------------------------------------------------------------------------------ 7-Scenes
SEVEN_SCENES = Path("/work/shared/data/7scenes-redkitchen")


def s7(edit, _ctx, path: Path) -> None:
    """Frames 0-2 of 7-Scenes redkitchen (the shared data) with ``edit(folder)`` applied."""
    if not SEVEN_SCENES.is_dir():
        raise FileNotFoundError(f"{SEVEN_SCENES} (7-Scenes frames) is not here")
    path.mkdir(parents=True)
    for f in [SEVEN_SCENES / "camera-intrinsics.txt", *sorted(SEVEN_SCENES.glob("frame-00000[012].*"))]:
        shutil.copy2(f, path / f.name)
    edit(path)


def pose_of(i: int, fn):
    def edit(seq: Path) -> None:
        p = seq / f"frame-{i:06d}.pose.txt"
        out = fn(np.loadtxt(p))
        rows = out if isinstance(out, (str, bytes)) else "\n".join(" ".join(repr(float(x)) for x in r) for r in out)
        fx.write(p, rows if isinstance(rows, bytes) or not rows else rows + "\n")
    return edit


def _translate(m):
    m = m.copy()
    m[:3, 3] = 1e6
    return m


def _singular(m):
    m = m.copy()
    m[:3, :3] = 0
    return m


S7_VARIANTS = {
    "all_depth_65535": lambda seq: [cv2.imwrite(str(p), np.full_like(cv2.imread(str(p), -1), 65535))
                                    for p in sorted(seq.glob("*.depth.png"))],
    "color_empty": put("frame-000001.color.jpg", b""),
    "depth_missing": rm("frame-000001.depth.png"),
    "depth_trunc": lambda seq: fx.truncated(seq / "frame-000001.depth.png", seq / "frame-000001.depth.png", 0.5),
    "intr_garbage": put("camera-intrinsics.txt", b"\xff" + fx.noise("intr", 100)),
    "intr_missing": rm("camera-intrinsics.txt"),
    "intr_nan": put("camera-intrinsics.txt", "nan nan nan\nnan nan nan\nnan nan nan\n"),
    "intr_zero": put("camera-intrinsics.txt", "0 0 0\n0 0 0\n0 0 1\n"),
    "ok": lambda seq: None,
    "one": rm("frame-00000[12].*"),
    "pose_1e6": pose_of(1, _translate),
    "pose_3x4": pose_of(1, lambda m: m[:3]),
    "pose_all_missing": rm("*.pose.txt"),
    "pose_empty": pose_of(1, lambda m: ""),
    "pose_garbage": pose_of(1, lambda m: "this is not a pose\n"),
    "pose_nan": pose_of(1, lambda m: np.full_like(m, np.nan)),
    "pose_singular": pose_of(1, _singular),
}


# ------------------------------------------------------------------------------------------------ trajectories
def traj(fn, ctx, path: Path) -> None:
    """A trajectory file from sim/office's ground truth rows (t tx ty tz qx qy qz qw) via ``fn``."""
    rows = np.loadtxt(ctx.p("sim/office/groundtruth.txt"), ndmin=2)
    out = fn(rows)
    fx.write(path, out if isinstance(out, (str, bytes)) else
             "\n".join(" ".join(repr(float(x)) for x in r) for r in out) + "\n")


def _million(_rows) -> str:
    return "".join(f"{i * 1e-6:.6f} 0 0 0 0 0 0 1\n" for i in range(1_000_000))


def _nomatch(rows):
    t = 1000 + np.arange(60) / 30
    return np.column_stack([t, np.repeat(rows[:2, 1:], 30, axis=0)])


TRAJ = {
    "empty": lambda r: "",
    "garbage": lambda r: b"\x00\x82" + fx.noise("traj", 500),
    "comments": lambda r: "# only\n# comments\n",
    "nan": lambda r: _cols(r, c1=np.nan),
    "inf": lambda r: _cols(r, c1=np.inf),
    "one": lambda r: r[:1],
    "seven_cols": lambda r: r[:, :7],
    "zero_quat": lambda r: _cols(r, c4=0, c5=0, c6=0, c7=0),
    "big": lambda r: _cols(r, c1=1e300, c2=1e300, c3=1e300),
    "million": _million,
    "dup": lambda r: np.vstack([r[:1], r]),
    "nomatch": _nomatch,
    "nonutf8": lambda r: b"# trajectory file\xff\n" + b"0 0 0 0 0 0 0 1\n",
    "nul": lambda r: "0\x00 0 0 0 0 0 0 1\n",
    "longline": lambda r: "0 " + "1" * 10_000_000 + "\n",
    "unnorm_quat": lambda r: np.hstack([r[:, :4], 2 * r[:, 4:]]),
    "static": lambda r: np.column_stack([r[:, :1], np.repeat(r[:1, 1:], len(r), axis=0)]),
}


# ------------------------------------------------------------------------------------------------ label folders
def evs(kind: str, ctx, path: Path) -> None:
    """eval-seg folders: ground truth = sim/office's first 3 label images as 0.png.. (ids below 21), and
    predictions derived from them."""
    src = pngs(ctx.p("sim/office/labels"))[:3]
    path.mkdir(parents=True)
    if kind == "none":
        return
    for i, p in enumerate(src):
        im = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.uint8) % 21
        out = path / (f"other_{i}.png" if kind == "other_names" else f"{i}.png")
        if kind in ("gt", "ok"):
            cv2.imwrite(str(out), im)
        elif kind == "small":
            cv2.imwrite(str(out), cv2.resize(im, (im.shape[1] // 2, im.shape[0] // 2),
                                             interpolation=cv2.INTER_NEAREST))
        elif kind == "garbage":
            fx.write(out, fx.noise(out.name, 3000))
        elif kind == "rgb":
            cv2.imwrite(str(out), cv2.cvtColor(im, cv2.COLOR_GRAY2BGR))
        elif kind == "16bit":
            cv2.imwrite(str(out), im.astype(np.uint16) + 5000)
        elif kind == "empty_files":
            fx.write(out, b"")
        elif kind == "all255":
            cv2.imwrite(str(out), np.full_like(im, 255))
        elif kind == "bomb":
            fx.png_bomb(out, bit_depth=8)
        elif kind == "other_names":
            cv2.imwrite(str(out), im)


def preds(kind: str, ctx, path: Path) -> None:
    """Precomputed predictions for sim/tiny's frames (``<timestamp>.npy``), from its label images."""
    path.mkdir(parents=True)
    k = len(json.loads(ctx.p("sim/tiny/labelset.json").read_text())["classes"])
    for p in pngs(ctx.p("sim/tiny/labels")):
        ids = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.int64)
        out = path / f"{p.stem}.npy"
        onehot = np.eye(k, dtype=np.float32)[ids]
        soft = (0.5 * onehot + 0.5 / k).astype(np.float32)
        arr = {"npy_ok": soft, "oh_ok": onehot, "npy_nan": np.full_like(soft, np.nan),
               "oh_partnan": np.where(np.arange(ids.size).reshape(ids.shape)[..., None] % 2 == 0, np.nan, onehot),
               "npy_wrongk": np.full((*ids.shape, 7), 1 / 7, np.float32),
               "oh_k7": (ids[..., None] == np.arange(7)).astype(np.float32),
               "npy_wrongsize": soft[::4, ::4], "oh_small": np.full((10, 64, k), 1 / k, np.float32),
               "npy_negative": np.full_like(soft, -5.0), "oh_unnorm": onehot * 7,
               "npy_int": ids}.get(kind)
        if kind == "npy_object":
            np.save(out, np.array([{"a": 1}], dtype=object), allow_pickle=True)
        elif kind == "npy_hugeshape":
            with open(out, "wb") as f:
                np.lib.format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False,
                                                         "shape": (*ids.shape, 10 ** 9)})
                f.write(b"\0" * 192)
        elif kind == "npz_bomb":
            out = path / f"{p.stem}.npz"
            with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z, z.open("probs.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False, "shape": (2**28,)})
                for _ in range(2**30 // 2**22):
                    f.write(b"\0" * 2**22)
            return  # one bomb is enough: the first frame's file is read first
        elif kind == "png_16bit_oob":
            cv2.imwrite(str(path / f"{p.stem}.png"), np.full(ids.shape, 40000, np.uint16))
        else:
            np.save(out, arr)


# ------------------------------------------------------------------------------------------------ weights
def weights(kind: str, ctx, path: Path) -> None:
    """Network weight files for --weights (torch files; ``evil`` carries a harmless print payload)."""
    import pickle

    import torch

    good = ctx.p("weights/fcn.pt")
    path.parent.mkdir(parents=True, exist_ok=True)
    if kind in ("evil", "evil_raw"):
        payload = Payload()
        if kind == "evil":
            torch.save(payload, path)
        else:
            path.write_bytes(pickle.dumps(payload))
        return
    if kind == "plain_dict":
        torch.save({"a": torch.zeros(3)}, path)
        return
    if kind == "tensor":
        torch.save(torch.zeros(3), path)
        return
    d = torch.load(good, weights_only=True)
    sd = d["state_dict"]
    if kind == "wrong_shape":
        first = next(iter(sd))
        sd[first] = torch.zeros(1)
    elif kind == "nan_weights":
        for k, v in sd.items():
            if v.is_floating_point():
                sd[k] = torch.full_like(v, float("nan"))
    elif kind == "bomb":
        sd["zz_bomb"] = torch.zeros(2**20)
    torch.save(d, path)


class Payload:
    """A pickle payload that would call print() if unpickled without weights_only (it must never run)."""

    def __reduce__(self):
        return (print, ("semmap probe: a pickle payload ran",))


def weights_dir(kind: str, ctx, path: Path) -> None:
    """A copy of the shipped weights/ folder (SEMMAP_WEIGHTS) with one thing wrong."""
    if kind == "empty":
        path.mkdir(parents=True)
        return
    shutil.copytree(ctx.p("weights"), path)
    manifest = path / "manifest.json"
    if kind == "badsha":
        text = manifest.read_text()
        import re
        manifest.write_text(re.sub(r'("sha256"\s*:\s*")[0-9a-f]+', lambda m: m.group(1) + "0" * 64, text))
    elif kind == "badmanifest":
        manifest.write_bytes(b"\x96" + fx.noise("manifest", 300))
    elif kind == "tampered":
        shutil.copy2(path / "fcn.pt", path / "pspnet.pt")
    elif kind == "swapped":
        shutil.copy2(ctx.p("outputs/runs/psp5/final.pt"), path / "pspnet.pt")


# ------------------------------------------------------------------------------------------------ training data
def train_folder(kind: str, ctx, path: Path) -> None:
    src = ctx.p("sim/train/a")
    if kind == "empty":
        path.mkdir(parents=True)
        return
    if kind.startswith("plain"):
        (path / "images").mkdir(parents=True)
        (path / "labels").mkdir()
        for p in pngs(src / "rgb"):
            shutil.copy2(p, path / "images" / p.name)
            if kind == "plain":
                shutil.copy2(src / "labels" / p.name, path / "labels" / p.name)
            elif kind == "plain_alllabel0":
                cv2.imwrite(str(path / "labels" / p.name), np.zeros(cv2.imread(str(p)).shape[:2], np.uint8))
        return
    fx.copytree(src, path)
    first = pngs(path / "labels")[0]
    if kind == "labels_missing":
        first.unlink()
    elif kind == "label_oob":
        im = cv2.imread(str(first), cv2.IMREAD_UNCHANGED)
        im[0, 0] = 250
        cv2.imwrite(str(first), im)
    elif kind == "label_size":
        cv2.imwrite(str(first), cv2.resize(cv2.imread(str(first), -1), (80, 60), interpolation=cv2.INTER_NEAREST))
    elif kind == "rgb_garbage":
        p = pngs(path / "rgb")[4]
        fx.write(p, fx.noise(p.name, 2000))
    elif kind == "labelset_garbage":
        fx.write(path / "labelset.json", b"\x00\x84" + fx.noise("lsg", 200))


# ------------------------------------------------------------------------------------------------ bags
def bag(kind: str, ctx, path: Path) -> None:
    """ROS bags: broken copies of bags/rec.bag and of a ROS 2 (sqlite3 / mcap) bag of the same frames."""
    import build_fixtures as bf

    rec = ctx.p("bags/rec.bag")
    rh = bf.ros_helpers()
    raw = {"empty.bag": b"", "magic_only.bag": b"#ROSBAG V2.0\n"}
    if kind in raw:
        return fx.write(path, raw[kind])
    if kind == "garbage.bag":
        return fx.write(path, fx.noise("bag", 4096))
    if kind == "trunc.bag":
        return fx.truncated(rec, path, 0.5)
    if kind == "trunc_head.bag":
        return fx.truncated(rec, path, 200)
    if kind == "ros1_as_v1.bag":
        return fx.write(path, b"#ROSBAG V1.2\n" + rec.read_bytes()[13:])
    frames = bf.load_frames(ctx, "sim/office", 4)
    path.parent.mkdir(parents=True, exist_ok=True)
    if kind == "nan_info.bag":
        cam = _force(frames[0].intrinsics, fx=float("nan"))
        return rh.write_bag(path, [_force(f, intrinsics=cam) for f in frames], poses="pose")
    if kind == "huge_image.bag":
        return rh.write_bag(path, [_force(f, rgb=np.zeros((2, 60000, 3), np.uint8)) for f in frames], poses="pose")
    if kind == "bad_encoding.bag":
        return rh.write_bag(path, frames, poses="pose", depth="yuv422")
    rh.write_bag(path, frames, kind="mcap" if "mcap" in kind else "sqlite3")
    _break_ros2(kind, path)


def _force(obj, **fields):
    """A copy of a (validated, frozen) dataclass with ``fields`` set without its checks: a hostile message."""
    out = copy_module.copy(obj)
    for k, v in fields.items():
        object.__setattr__(out, k, v)
    return out


def _break_ros2(kind: str, path: Path) -> None:
    import re

    meta = path / "metadata.yaml"
    db = next(iter(sorted(path.glob("*.db3")) + sorted(path.glob("*.mcap"))))
    if kind == "r2_meta_garbage":
        fx.write(meta, b"\xdf" + fx.noise("meta", 300))
    elif kind == "r2_no_db":
        db.unlink()
    elif kind in ("r2_db_trunc", "r2_mcap_trunc"):
        fx.truncated(db, db, 0.5)
    elif kind == "r2_db_garbage":
        fx.write(db, fx.noise("db", 8192))
    elif kind == "r2_meta_huge_count":
        meta.write_text(re.sub(r"message_count: \d+", "message_count: 1000000000000000000", meta.read_text()))
    elif kind == "r2_meta_empty":
        fx.write(meta, b"")


# ------------------------------------------------------------------------------------------------ permissions
def perm(ctx, path: Path) -> None:
    """h/perm: unreadable (mode 000) inputs and a mode-555 output folder (they bite only without DAC override)."""
    path.mkdir(parents=True)
    for name, src in (("map.ot", "outputs/office/map.ot"), ("map.semmap", "outputs/office/map.semmap"),
                      ("voxelgrid.ply", "outputs/maps3/voxelgrid.ply"), ("traj.txt", "sim/office/groundtruth.txt")):
        shutil.copy2(ctx.p(src), path / name)
        (path / name).chmod(0)
    for name in ("seq", "seq2", "seq3", "seq4"):
        fx.copytree(ctx.p("sim/tiny"), path / name)
    pngs(path / "seq" / "depth")[0].chmod(0)
    (path / "seq2" / "rgb.txt").chmod(0)
    (path / "seq3" / "labelset.json").chmod(0)
    for name in ("w", "nc", "outdir"):
        (path / name).mkdir()
        (path / name).chmod(0o777)
    (path / "outdir").chmod(0o555)
    (path / "seq4" / "depth").chmod(0)


# ------------------------------------------------------------------------------------------------ mounts
def tmpfs(size: str, read_only: bool, _ctx, path: Path) -> None:
    """A tmpfs of ``size`` (read-only for ro/); without the privilege: a mode-555 folder (ro/) or nothing (full/)."""
    path.mkdir(parents=True)
    opts = f"size={size}" + (",ro" if read_only else "")
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True, text=True)
    if proc.returncode == 0:
        return
    if read_only:
        path.chmod(0o555)
        NOT_REPRODUCIBLE["ro"] = f"mode 555 instead of a read-only mount ({proc.stderr.strip()}); root still writes"
        return
    path.rmdir()
    raise RuntimeError(f"cannot mount a 2 MB tmpfs ({proc.stderr.strip()}); the disk-full cases are not reproducible")


# ------------------------------------------------------------------------------------------------ the table
def base_fixtures(b) -> dict:
    """Sequences, earlier good runs and tools (``b`` = the build_fixtures module)."""
    small = ("--image-size", "320x240")
    return {
        ".venv/bin/semmap": b.tools,
        "sim/office": b.simulate("--frames", "30"),
        "sim/tiny": b.simulate("--frames", "3", *small),
        "sim/room": b.simulate("--scene-seed", "5", "--frames", "40", *small),
        "sim/room-again": b.simulate("--scene-seed", "5", "--trajectory-seed", "7", "--frames", "10", *small),
        "seqs/a": b.simulate("--scene-seed", "1", "--frames", "10", *small),
        "seqs/b": b.simulate("--scene-seed", "2", "--frames", "10", *small),
        "sim/train": partial(b.train_data, seeds=(100, 101), frames=10),
        "sim/val": b.simulate("--scene-seed", "150", "--frames", "4", "--image-size", "160x120"),
        "bags/rec.bag": b.ros1_bag,
        "outputs/office": b.semmap_run("sim/office", "--semantics", "oracle"),
        "outputs/maps3": b.semmap_run("sim/office", "--maps", "octomap,voxelgrid,points", "--semantics",
                                 "oracle", "--max-frames", "10"),
        "outputs/objects": b.semmap_run("sim/office", "--instances", "oracle", "--semantics", "oracle",
                                   "--max-frames", "10"),
        "outputs/room-map": b.semmap_run("sim/room", "--semantics", "oracle"),
        "outputs/runs/fcn2": partial(b.train_run, model="fcn", iterations=20),
        "outputs/runs/cbam": partial(b.train_run, model="cbam-pspnet", iterations=2),
        "outputs/runs/psp5": partial(b.train_run, model="pspnet", iterations=5),
        "h/ckpt_saved": b.checkpoint_folder,
    }


def map_fixtures() -> dict:
    ot, bt, sm = "outputs/office/map.ot", "outputs/office/map.bt", "outputs/office/map.semmap"
    vg, pt, vply = "outputs/maps3/voxelgrid.semmap", "outputs/maps3/points.semmap", "outputs/maps3/voxelgrid.ply"
    t: dict = {}
    for ext, src in (("ot", ot), ("bt", bt), ("semmap", sm), ("ply", vply)):
        t[f"h/empty.{ext}"] = partial(data, b"")
        t[f"h/garbage.{ext}"] = garbage
        t[f"h/trunc.{ext}"] = partial(trunc, src, 0.5)
        t[f"h/trunc10.{ext}"] = partial(trunc, src, 10)
    for ext in ("ot", "bt", "semmap", "ply", "bag", "txt"):
        t[f"h/sparse.{ext}"] = partial(special, "sparse")
    for ext in ("ot", "semmap", "ply", "bag", "txt"):
        t[f"h/zero.{ext}"] = partial(special, "zero")
    for ext in ("ot", "semmap", "ply", "bag", "txt"):
        t[f"h/fifo.{ext}"] = partial(special, "fifo")
    for ext in ("ot", "semmap"):
        t[f"h/dir.{ext}"] = partial(special, "dir")
        t[f"h/loop.{ext}"] = partial(special, "loop")
    t |= {
        "h/trunc_vg.semmap": partial(trunc, vg, 0.5), "h/trunc_pt.semmap": partial(trunc, pt, 0.5),
        "h/neg_size.ot": partial(small_octomap, "0.05", size="-5"),
        "h/res0.ot": partial(small_octomap, "0.0"), "h/resneg.ot": partial(small_octomap, "-0.05"),
        "h/resnan.ot": partial(small_octomap, "nan"), "h/resinf.ot": partial(small_octomap, "inf"),
        "h/res1e300.ot": partial(small_octomap, "1e300"),
        "h/unknown_tree.ot": partial(octomap, ot, id="SuperTree"),
        "h/size_text.ot": partial(octomap, ot, size="lots"),
        "h/nodata.ot": partial(octomap, ot, drop_data=True),
        "h/longline.ot": partial(octomap_text, "# Octomap OcTree file\n# " + "x" * 2_000_000 + "\n"),
        "h/huge_count.ot": partial(octomap, ot, size="100000000000", tree=b"\0" * 64),
        "h/huge_count.bt": partial(octomap, bt, size="99999999999"),
        "h/bt_as_ot.ot": partial(copy, bt), "h/ot_as_bt.bt": partial(copy, ot),
        "h/resnan.bt": partial(octomap, bt, size="100", res="nan"),
        "h/trailing.ot": lambda ctx, p: fx.write(p, ctx.p(ot).read_bytes() + fx.noise("trail", 4096)),
        "h/res1e300_ok.ot": partial(octomap, ot, res="1e300"), "h/res1e-300_ok.ot": partial(octomap, ot, res="1e-300"),
        "h/res_big10.ot": partial(octomap, ot, res="10"), "h/res1e300_ok.bt": partial(octomap, bt, res="1e300"),
        "h/res_nan.semmap": partial(sem, sm, _set("resolution", float("nan"))),
        "h/res_neg.semmap": partial(sem, sm, _set("resolution", -0.05)),
        "h/res_zero.semmap": partial(sem, sm, _set("resolution", 0.0)),
        "h/version999.semmap": partial(sem, sm, _set("version", 999)),
        "h/format_other.semmap": partial(sem, sm, _set("format", "not-semmap")),
        "h/hdr_null.semmap": partial(sem_raw, None), "h/hdr_string.semmap": partial(sem_raw, "a string"),
        "h/res_true.semmap": partial(sem, sm, _set("resolution", True)),
        "h/res_huge.semmap": partial(sem, sm, _set("resolution", 1e308)),
        "h/missing_member.semmap": partial(sem_raw, ..., drop="logodds"),
        "h/missing_header.semmap": partial(sem_raw, ..., drop="header"),
        "h/object_member.semmap": partial(sem, sm, _arr("packed", lambda a: np.array(list(a[:10]), dtype=object))),
        "h/len_mismatch.semmap": partial(sem, sm, _arr("logodds", lambda a: np.concatenate([a, a[:7]]))),
        "h/len_mismatch_vg.semmap": partial(sem, vg, _arr("logodds", lambda a: np.concatenate([a, a[:7]]))),
        "h/len_mismatch_pt.semmap": partial(sem, pt, _arr("logodds", lambda a: np.concatenate([a, a[:7]]))),
        "h/all_nan.semmap": partial(sem, sm, _arr("logodds", lambda a: np.full_like(a, np.nan))),
        "h/all_nan_vg.semmap": partial(sem, vg, _arr("logodds", lambda a: np.full_like(a, np.nan))),
        "h/complex.semmap": partial(sem, sm, _arr("packed", lambda a: a.astype(np.complex128))),
        "h/many_classes.semmap": partial(sem, sm, _many_classes),
        "h/bomb.semmap": semmap_bomb,
        "h/ply_huge.ply": partial(ply_xyz, 1e30), "h/ply_neg.ply": partial(ply_xyz, -1.0),
        "h/ply_xyzonly.ply": partial(ply_xyz, 1.0),
        "h/ply_ascii.ply": partial(ply, _replace("format", "format ascii 1.0")),
        "h/ply_noend.ply": lambda ctx, p: fx.write(p, ctx.p(vply).read_bytes().replace(b"end_header\n", b"")),
        "h/ply_bigendian.ply": partial(ply, _replace("format", "format binary_big_endian 1.0")),
        "h/ply_nan.ply": ply_nan, "h/ply_hugecount.ply": ply_hugecount,
        "h/ply_negcount.ply": partial(ply, ply_vertex_count("-1")),
        "h/ply_zerocount.ply": ply_zero, "h/ply_floatcount.ply": partial(ply, ply_vertex_count("1.5")),
        "h/ply_extra_element.ply": partial(ply, lambda ls: [*ls, "property list uchar int vertex_indices"]),
        "h/map_\udcff\udcfe.ot": partial(copy, ot), "h/map with spaces.ot": partial(copy, ot),
        "h/L": long_path,
    }
    return t


def input_fixtures() -> dict:
    t: dict = {f"h/ds/tum_{k}": partial(tum, v) for k, v in TUM_VARIANTS.items()}
    t["h/ds/tum_static"] = static_seq
    t |= {f"h/ds/s7_{k}": partial(s7, v) for k, v in S7_VARIANTS.items()}
    t |= {f"h/traj/{k}.txt": partial(traj, v) for k, v in TRAJ.items()}
    for k in ("gt", "ok", "small", "garbage", "rgb", "16bit", "empty_files", "none", "other_names", "bomb"):
        t[f"h/evs/{'gt' if k == 'gt' else 'pred_' + k}"] = partial(evs, k)
    t["h/evs/gt_all255"] = partial(evs, "all255")
    t["h/evs/gt_bomb"] = partial(evs, "bomb")
    for k in ("npy_ok", "npy_nan", "npy_wrongk", "npy_wrongsize", "npy_object", "npy_hugeshape", "npz_bomb",
              "npy_negative", "npy_int", "png_16bit_oob", "oh_ok", "oh_k7", "oh_small", "oh_partnan", "oh_unnorm"):
        t[f"h/pre/{k}"] = partial(preds, k)
    for k in ("empty", "garbage", "trunc"):
        t[f"h/w/{k}.pt"] = {"empty": partial(data, b""), "garbage": garbage,
                            "trunc": partial(trunc, "weights/fcn.pt", 0.5)}[k]
    for k in ("evil", "evil_raw", "wrong_shape", "nan_weights", "plain_dict", "tensor", "bomb"):
        t[f"h/w/{k}.pt"] = partial(weights, k)
    for k in ("badsha", "tampered", "badmanifest", "empty", "swapped"):
        t[f"h/w/wd_{k}"] = partial(weights_dir, k)
    for k in ("empty", "labels_missing", "label_oob", "label_size", "rgb_garbage", "labelset_garbage", "plain",
              "plain_nolabels", "plain_alllabel0"):
        t[f"h/train/{k}"] = partial(train_folder, k)
    t |= {
        "h/train/classmap_garbage.json": partial(data, b'{"\xc3\x28": 1}'),
        "h/train/classmap_types.json": partial(data, '{"map": [1, 2], "default": 0}'),
        "h/train/classmap_unknown.json": partial(data, '{"map": {"1": "dragon"}, "default": 0}'),
        "h/batch/garbage.json": partial(data, b"\x96" + fx.noise("batch", 200)),
        "h/batch/list.json": partial(data, "[1, 2, 3]"),
        "h/batch/badtype.json": partial(data, '{"mapping": {"resolution": "fine"}}'),
        "h/batch/tinyres.json": partial(data, '{"mapping": {"resolution": 1e-05}}'),
        "h/batch/extra.json": partial(data, '{"unknown_field": 1}'),
        "h/batch/x/a": partial(copy, "seqs/a"), "h/batch/y/a": partial(copy, "seqs/b"),
    }
    for k in ("empty.bag", "garbage.bag", "trunc.bag", "trunc_head.bag", "magic_only.bag", "ros1_as_v1.bag",
              "r2_meta_garbage", "r2_no_db", "r2_db_trunc", "r2_db_garbage", "r2_meta_huge_count", "r2_meta_empty",
              "r2_mcap_trunc", "nan_info.bag", "huge_image.bag", "bad_encoding.bag"):
        t[f"h/bags/{k}"] = partial(bag, k)
    return t


def victim_fixtures() -> dict:
    """Victims (good copies a case may overwrite) and the mounts: rebuilt on every build (``ALWAYS``)."""
    return {
        "h/victim_in": partial(copy, "sim/tiny"), "h/v2": partial(copy, "sim/tiny"),
        "h/v3": partial(copy, "sim/tiny"), "h/evs2": lambda ctx, p: (evs("gt", ctx, p / "gt"),
                                                                       evs("ok", ctx, p / "pred_ok")),
        "h/victim.ot": partial(copy, "outputs/office/map.ot"),
        "h/perm": perm,
        "ro": partial(tmpfs, "1m", True), "full": partial(tmpfs, "2m", False),
    }


def table(b) -> dict:
    """Every fixture in build order: path relative to the scratch folder -> builder(ctx, path)."""
    return base_fixtures(b) | map_fixtures() | input_fixtures() | victim_fixtures()
