"""semmap train: data folders (simulator and plain layouts, class maps, bad files), median-frequency weights
(eqs. 1-2), poly learning rate, a short run with its outputs, exact resume after an interruption."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import run_cli, write_png
from semmap.errors import ConfigError, DatasetError
from semmap.perception.networks.registry import load_weights
from semmap.perception.registry import make_segmenter
from semmap.train.class_weights import median_frequency_weights
from semmap.train.data import gather
from semmap.train.trainer import Trainer, TrainSettings, batch_indices, poly_lr, train
from semmap.types import LabelSet

K = 4
SIZE = (32, 24)


def write_plain(root: Path, n: int = 6, *, size: tuple[int, int] = (40, 30), depth: bool = True,
                max_id: int = K - 1) -> Path:
    """A plain-layout folder: images/, labels/ (blocks of classes), depth/ (mm), labelset.json."""
    rng = np.random.default_rng(len(str(root)))
    w, h = size
    for i in range(n):
        labels = np.zeros((h, w), np.uint8)
        labels[: h // 2] = 1
        labels[h // 2:, : w // 2] = 2
        labels[h // 2:, w // 2:] = max_id if i % 2 else 1
        rgb = (labels[..., None] * 60 + rng.integers(0, 40, (h, w, 3))).astype(np.uint8)
        write_png(root / "images" / f"f{i:03d}.png", rgb[..., ::-1])
        write_png(root / "labels" / f"f{i:03d}.png", labels)
        if depth:
            write_png(root / "depth" / f"f{i:03d}.png", (1000 + 500 * labels.astype(np.uint16)))
    LabelSet.generic(K).save(root / "labelset.json")
    return root


def settings(tmp_path: Path, data: Path, **kw) -> TrainSettings:
    base = dict(model="pspnet", data=(data,), out=tmp_path / "run", iterations=2, batch=2, input_size=SIZE,
                width=0.125, eval_every=1, threads=1)
    return TrainSettings(**(base | kw))


def test_median_frequency_weights_follow_eqs_1_and_2() -> None:
    labels = np.zeros((2, 2, 4), np.uint8)
    labels[0] = [[1, 1, 1, 1], [1, 1, 2, 2]]  # class 1: 6 + 8 px in 2 images; class 2: 2 px in 1; class 3: 0
    labels[1] = [[1, 1, 1, 1], [1, 1, 1, 1]]
    w = median_frequency_weights(labels, 4)
    f1, f2 = 14 / (2 * 8), 2 / (1 * 8)  # eq. 1: F_c = N_c / (P_c W H)
    med = np.median([f1, f2])
    np.testing.assert_allclose(w, [0, med / f1, med / f2, 0], rtol=1e-6)  # eq. 2; void and absent classes: 0


def test_poly_learning_rate() -> None:
    assert poly_lr(0.01, 0, 100, 0.9) == 0.01
    assert poly_lr(0.01, 50, 100, 0.9) == pytest.approx(0.01 * 0.5**0.9)
    assert poly_lr(0.01, 100, 100, 0.9) == 0.0


def test_every_image_once_per_epoch() -> None:
    seen = np.concatenate([batch_indices(3, i, 4, 10) for i in range(5)])  # 20 = two epochs of 10
    assert sorted(seen[:10]) == list(range(10)) and sorted(seen[10:]) == list(range(10))


def test_short_run_writes_logs_curve_and_usable_weights(tmp_path: Path) -> None:
    data = write_plain(tmp_path / "data")
    result = train(settings(tmp_path, data))
    out = tmp_path / "run"
    for name in ("config.json", "class_weights.json", "log.csv", "log.json", "curve.png", "last.pt", "best.pt",
                 "final.pt"):
        assert (out / name).is_file(), name
    rows = json.loads((out / "log.json").read_text())["rows"]
    assert [r["iteration"] for r in rows] == [1, 2] and result.iterations == 2
    assert 0.0 <= rows[-1]["val_miou"] <= 1.0
    seg = make_segmenter("pspnet", weights=out / "best.pt")
    assert seg.predict(np.zeros((30, 40, 3), np.uint8)).labels.shape == (30, 40, 3)
    with pytest.raises(ConfigError, match="--resume"):  # a finished run is not overwritten by accident
        Trainer(settings(tmp_path, data))


def test_resume_after_an_interruption_continues_exactly(tmp_path: Path) -> None:
    data = write_plain(tmp_path / "data")
    full = train(settings(tmp_path / "a", data, iterations=4, eval_every=2, checkpoint_every=1))
    part = train(settings(tmp_path / "b", data, iterations=4, eval_every=2, checkpoint_every=1), stop_after=2)
    assert part.iterations == 2 and not (tmp_path / "b" / "run" / "final.pt").exists()
    resumed = train(settings(tmp_path / "b", data, iterations=4, eval_every=2, checkpoint_every=1), resume=True)
    def scores(rows):
        return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]

    assert resumed.iterations == 4 and scores(resumed.rows) == scores(full.rows)
    a, b = load_weights(full.final).model.state_dict(), load_weights(resumed.final).model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ConfigError, match="different settings"):
        Trainer(settings(tmp_path / "b", data, iterations=4, lr=0.5), resume=True)


@pytest.mark.slow
def test_rgbd_net_trains_on_a_simulated_folder(tmp_path: Path) -> None:
    from semmap.sim.export import simulate_sequence

    root = simulate_sequence(tmp_path / "sim", scene_seed=7, kind="office", size="small", trajectory="loop",
                             frames=3, image_size=SIZE, fps=1.0)
    info = json.loads((root / "scene.json").read_text())
    assert info["intrinsics"]["width"] == SIZE[0] and info["intrinsics"]["fx"] == pytest.approx(525.0 * 32 / 640)
    ds = gather([root], SIZE, need_depth=True)
    assert ds.rgb.shape == (3, 24, 32, 3) and ds.depth is not None and ds.depth.max() > 500  # millimetres
    result = train(settings(tmp_path, root, model="rgbd-net", val=(root,), iterations=1))
    assert load_weights(result.final).spec.model == "rgbd-net"


def test_bad_data_errors_name_the_file(tmp_path: Path) -> None:
    data = write_plain(tmp_path / "data", n=2)
    (data / "labels" / "f001.png").unlink()
    with pytest.raises(DatasetError, match=r"f001\.png.*no label image"):
        gather([data], SIZE)
    data = write_plain(tmp_path / "sizes", n=2)
    write_png(data / "labels" / "f000.png", np.zeros((10, 10), np.uint8))
    with pytest.raises(DatasetError, match=r"labels/f000\.png: label image is 10x10"):
        gather([data], SIZE)
    data = write_plain(tmp_path / "range", n=2, max_id=9)
    with pytest.raises(DatasetError, match=r"labels/f001\.png: class id 9 is outside"):
        gather([data], SIZE)
    (tmp_path / "map.json").write_text(json.dumps({"map": {"1": 1, "2": "class_2", "9": 3}}))
    ds = gather([data], SIZE, class_map_path=tmp_path / "map.json")
    assert set(np.unique(ds.labels)) == {1, 2, 3}
    nodepth = write_plain(tmp_path / "nodepth", n=2, depth=False)
    with pytest.raises(DatasetError, match="no depth image"):
        gather([nodepth], SIZE, need_depth=True)


@pytest.mark.slow
def test_cli_train_and_its_one_line_errors(tmp_path: Path) -> None:
    data = write_plain(tmp_path / "data")
    out = tmp_path / "run"
    r = run_cli("train", "--model", "fcn", "--data", str(data), "--out", str(out), "--iterations", "2", "--batch",
                "2", "--input-size", "32x24", "--width", "0.125", "--eval-every", "1", "--threads", "1")
    assert r.returncode == 0, r.stderr
    assert load_weights(out / "best.pt").spec.model == "fcn"
    (data / "labels" / "f002.png").unlink()
    r = run_cli("train", "--model", "fcn", "--data", str(data), "--out", str(tmp_path / "run2"))
    assert r.returncode == 1 and "f002.png" in r.stderr and "Traceback" not in r.stderr
    with pytest.raises(ConfigError, match="--device"):
        settings(tmp_path, data, device="gpu")
