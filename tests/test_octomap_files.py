"""OctoMap .ot / .bt files and the native format: round trips through the real OctoMap library, pruning,
and clear errors on truncated or malformed files."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pyoctomap
import pytest

from naive import EMPTY
from semmap.errors import FormatError
from semmap.io.native import load_map, save_map
from semmap.io.octomap_files import decode_octomap, read_octomap, write_bt, write_ot
from semmap.keys import coords_to_keys
from semmap.maps.octree_tree import build_tree
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.types import LabelSet, TopKProbs


@pytest.fixture(scope="module")
def semantic_map() -> SemanticOctoMap:
    rng = np.random.default_rng(0)
    labels = LabelSet.generic(6)
    m = SemanticOctoMap(0.05, label_set=labels)
    for i in range(3):
        pts = rng.uniform(-1, 1, (6000, 3)) + np.array([0.0, 0.0, 2.5])
        lab = rng.integers(1, 6, len(pts)).astype(np.uint16)
        sem = TopKProbs(np.stack([lab, np.full_like(lab, EMPTY), np.full_like(lab, EMPTY)], 1),
                        np.tile(np.array([0.7, 0, 0], np.float32), (len(pts), 1)))
        m.insert_points(pts, [0.1 * i, 0, 0], colors=rng.integers(0, 250, (len(pts), 3), dtype=np.uint8),
                        semantics=sem)
    return m


def _pyoctomap_leaves(tree):
    out = {}
    for leaf in tree.begin_leafs():
        key = tuple(coords_to_keys(np.array([leaf.getCoordinate()]), tree.getResolution())[0])
        out[(key, round(leaf.getSize(), 6))] = tree.isNodeOccupied(leaf)
    return out


@pytest.mark.slow
def test_pyoctomap_reads_our_ot_and_bt_with_the_same_leaves(semantic_map, tmp_path):
    nodes = semantic_map.tree()
    write_ot(tmp_path / "m.ot", nodes, semantic_map.resolution)
    write_bt(tmp_path / "m.bt", nodes, semantic_map.resolution)
    ot = pyoctomap.ColorOcTree(0.1).read(str(tmp_path / "m.ot"))
    bt = pyoctomap.OcTree(0.1)
    assert bt.readBinary(str(tmp_path / "m.bt"))
    assert ot.getResolution() == pytest.approx(0.05) and bt.getResolution() == pytest.approx(0.05)
    n_occ = int((nodes.is_leaf & semantic_map.is_occupied(nodes.values)).sum())
    assert sum(_pyoctomap_leaves(ot).values()) == n_occ == sum(_pyoctomap_leaves(bt).values())
    assert _pyoctomap_leaves(ot) == _pyoctomap_leaves(bt)
    assert ot.size() == len(nodes) == bt.size()


def test_ot_leaves_carry_log_odds_and_class_colours(semantic_map, tmp_path):
    nodes = semantic_map.tree(color_mode="class")
    write_ot(tmp_path / "m.ot", nodes, semantic_map.resolution)
    ot = pyoctomap.ColorOcTree(0.1).read(str(tmp_path / "m.ot"))
    vox = semantic_map.voxels()
    palette = {tuple(c) for c in semantic_map.label_set.colors.tolist()}
    checked = 0
    for leaf in ot.begin_leafs():
        if ot.isNodeOccupied(leaf) and leaf.getSize() == pytest.approx(0.05):
            assert tuple(leaf.getColor()) in palette
            checked += 1
    assert checked == len(vox)


def test_unclassified_voxels_show_grey_in_class_mode_and_colour_in_rgb_mode(tmp_path):
    """Background (class 0) voxels keep their brightness but not their hue, so class colours stand out."""
    m = SemanticOctoMap(0.1, label_set=LabelSet.generic(3))
    pts = np.array([[0.05, 0.05, 1.05], [0.55, 0.05, 1.05]])
    sem = TopKProbs(np.array([[0, EMPTY, EMPTY], [2, EMPTY, EMPTY]], np.uint16),
                    np.array([[0.9, 0, 0], [0.9, 0, 0]], np.float32))
    red = np.array([[200, 10, 10], [200, 10, 10]], np.uint8)
    m.insert_points(pts, [0.0, 0.0, 0.0], colors=red, semantics=sem)
    for mode in ("class", "rgb"):
        write_ot(tmp_path / f"{mode}.ot", m.tree(color_mode=mode), m.resolution)
        ot = pyoctomap.ColorOcTree(0.1).read(str(tmp_path / f"{mode}.ot"))
        background, classified = (np.array(ot.search(p).getColor()) for p in pts)
        if mode == "class":
            assert background[0] == background[1] == background[2] and 64 <= background[0] <= 192
            np.testing.assert_array_equal(classified, m.label_set.colors[2])
        else:
            np.testing.assert_array_equal(background, red[0])
            np.testing.assert_array_equal(classified, red[0])


def test_our_reader_reads_what_pyoctomap_writes(tmp_path):
    rng = np.random.default_rng(1)
    tree = pyoctomap.ColorOcTree(0.1)
    pts = rng.uniform(-2, 2, (3000, 3))
    tree.insertPointCloud(pts, np.zeros(3))
    for p in pts[:200]:
        tree.setNodeColor(p, 10, 200, 30)
    tree.updateInnerOccupancy()
    assert tree.write(str(tmp_path / "c.ot"))
    plain = pyoctomap.OcTree(0.1)
    plain.insertPointCloud(pts, np.zeros(3))
    assert plain.writeBinary(str(tmp_path / "p.bt"))
    c = read_octomap(tmp_path / "c.ot")
    b = read_octomap(tmp_path / "p.bt")
    assert c.tree_type == "ColorOcTree" and b.tree_type == "OcTree"
    assert c.num_nodes == tree.size()
    assert int(c.occupied().sum()) == sum(_pyoctomap_leaves(tree).values())
    assert int(b.occupied().sum()) == sum(_pyoctomap_leaves(plain).values())
    assert (c.colors[c.occupied()] == [10, 200, 30]).all(axis=1).sum() > 0


def test_pruning_merges_only_identical_children():
    base = np.array([[32768 + x, 32768 + y, 32768 + z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
    vals = np.full(8, 2.0, np.float32)
    colors = np.full((8, 3), 100, np.uint8)
    labels = np.full(8, 3, np.uint16)
    confs = np.full(8, 0.9, np.float32)
    pruned = build_tree(base, vals, colors, labels, confs)
    assert pruned.is_leaf.sum() == 1 and len(pruned) == 16  # 15 ancestors + the merged leaf
    for what in ("labels", "confs", "colors", "vals"):
        args = {"vals": vals.copy(), "colors": colors.copy(), "labels": labels.copy(), "confs": confs.copy()}
        args[what][3] = args[what][3] + 1 if what != "colors" else 7
        t = build_tree(base, args["vals"], args["colors"], args["labels"], args["confs"])
        assert t.is_leaf.sum() == 8, f"children differing in {what} must not be pruned"
    seven = build_tree(base[:7], vals[:7], colors[:7], labels[:7], confs[:7])
    assert seven.is_leaf.sum() == 7, "a parent with a missing child is never pruned"


def test_inner_nodes_take_the_max_occupancy_and_the_mean_colour():
    keys = np.array([[32768, 32768, 32768], [32769, 32768, 32768]])
    t = build_tree(keys, np.array([-1.0, 2.0], np.float32), np.array([[10, 20, 30], [30, 40, 50]], np.uint8),
                   np.array([1, 2], np.uint16), np.array([0.5, 0.6], np.float32))
    parent = np.flatnonzero(t.depths == 15)[0]
    assert t.values[parent] == 2.0 and t.colors[parent].tolist() == [20, 30, 40]


@pytest.mark.parametrize("cut", [0, 10, 60, 95, -1, -9])
def test_truncated_octomap_files_give_a_clear_error(semantic_map, tmp_path, cut):
    nodes = semantic_map.tree()
    for name, writer in (("m.ot", write_ot), ("m.bt", write_bt)):
        writer(tmp_path / name, nodes, semantic_map.resolution)
        data = (tmp_path / name).read_bytes()
        end = cut if cut >= 0 else len(data) + cut
        with pytest.raises(FormatError, match=re.escape(name)):
            decode_octomap(data[:end], name)


@pytest.mark.parametrize("content", [b"", b"hello\nworld\n",
                                     b"# Octomap OcTree file\nid Weird\nsize 1\nres 0.1\ndata\n\x00",
                                     b"# Octomap OcTree file\nid OcTree\nsize x\nres 0.1\ndata\n",
                                     b"# Octomap OcTree file\n" + b"#\n" * 100,
                                     b"# Octomap OcTree binary file\nid OcTree\nsize 3\nres 0.1\ndata\n\xff\xff"])
def test_malformed_octomap_files_give_a_clear_error(tmp_path, content):
    path = tmp_path / "bad.ot"
    path.write_bytes(content)
    with pytest.raises(FormatError, match=r"bad\.ot"):
        read_octomap(path)


def test_native_round_trip_is_exact(semantic_map, tmp_path):
    save_map(tmp_path / "m.semmap", semantic_map)
    loaded = load_map(tmp_path / "m.semmap")
    a, b = semantic_map.cells(), loaded.cells()
    for name in a.__dataclass_fields__:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and np.array_equal(x, y), name
    assert loaded.resolution == semantic_map.resolution
    assert loaded.label_set.names == semantic_map.label_set.names
    assert loaded.fusion == semantic_map.fusion and loaded.occupancy == semantic_map.occupancy
    # the loaded map keeps working
    loaded.insert_points(np.array([[0.0, 0.0, 1.0]]), np.zeros(3))


@pytest.mark.parametrize("damage", ["truncate", "garbage", "missing"])
def test_damaged_native_files_give_a_clear_error(semantic_map, tmp_path, damage):
    path = tmp_path / "m.semmap"
    save_map(path, semantic_map)
    data = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        path.write_bytes(b"PK\x03\x04" + os.urandom(200))
    else:
        path.unlink()
    with pytest.raises(FormatError, match=r"m\.semmap"):
        load_map(path)


def test_a_failed_write_leaves_the_previous_file_intact(semantic_map, tmp_path, monkeypatch):
    path = tmp_path / "m.semmap"
    save_map(path, semantic_map)
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(OSError):
        save_map(path, semantic_map)
    assert path.read_bytes() == before
    assert [p.name for p in Path(tmp_path).iterdir()] == ["m.semmap"], "no temporary file left behind"
