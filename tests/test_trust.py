"""Trust but verify (issue 31, deliverable 6; probe cases S7-S13 and T34): weights checked against the manifest's
sha256, NaN weights and NaN network outputs stopped, precomputed predictions of the wrong size, K or with NaN
refused, depth of an implausible unit warned about, torch's hostile-pickle message replaced, and NaN options of
``semmap localize`` refused before any numba kernel."""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import make_room_frames, room_label_set
from semmap.errors import ConfigError, FormatError
from semmap.perception.networks.registry import NetworkSpec, build_network, load_weights, save_weights
from semmap.perception.registry import MANIFEST, make_segmenter

ROOM_SIZE = (80, 60)


def _tiny_fcn(path: Path, *, poison: float | None = None) -> Path:
    """A small FCN weight file for the room's 7 classes (``poison`` written into its first tensor)."""
    torch.manual_seed(0)
    spec = NetworkSpec("fcn", num_classes=7, width=0.25, depth=18)
    model = build_network(spec)
    if poison is not None:
        with torch.no_grad():
            next(model.parameters()).view(-1)[0] = poison
    return save_weights(path, model, spec, room_label_set(), ROOM_SIZE)


def _manifest(folder: Path, sha: str) -> None:
    (folder / MANIFEST).write_text(json.dumps({"networks": {"fcn": {"file": "fcn.pt", "sha256": sha}}}))


@pytest.fixture(scope="module")
def weights_file(tmp_path_factory) -> Path:
    return _tiny_fcn(tmp_path_factory.mktemp("w") / "fcn.pt")


@pytest.fixture
def shipped(tmp_path, monkeypatch, weights_file) -> Path:
    """A folder of shipped weights (``$SEMMAP_WEIGHTS``) holding fcn.pt, its manifest still to write."""
    folder = tmp_path / "weights"
    folder.mkdir()
    (folder / "fcn.pt").write_bytes(weights_file.read_bytes())
    monkeypatch.setenv("SEMMAP_WEIGHTS", str(folder))
    return folder


# ------------------------------------------------------------------ S10: the manifest's sha256
def test_shipped_weights_matching_the_manifest_load_without_a_word(shipped, caplog) -> None:
    _manifest(shipped, hashlib.sha256((shipped / "fcn.pt").read_bytes()).hexdigest())
    with caplog.at_level(logging.WARNING, logger="semmap"):
        seg = make_segmenter("fcn")
    assert len(seg.label_set) == 7 and "sha256" not in caplog.text


def test_shipped_weights_with_another_sha256_are_refused_in_one_line(shipped) -> None:
    _manifest(shipped, "0" * 64)
    with pytest.raises(ConfigError, match=r"fcn\.pt: sha256 .* differs from .*manifest\.json.*--trust-weights") as e:
        make_segmenter("fcn")
    assert "\n" not in str(e.value)
    # the same file named by --weights is still the manifest's: checked too
    with pytest.raises(ConfigError, match="differs"):
        make_segmenter("fcn", weights=shipped / "fcn.pt")


def test_trust_weights_uses_them_with_a_warning(shipped, caplog) -> None:
    _manifest(shipped, "0" * 64)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        seg = make_segmenter("fcn", trust_weights=True)
    assert len(seg.label_set) == 7
    assert "differs" in caplog.text and "--trust-weights" in caplog.text


def test_trust_weights_reaches_the_segmenter_from_the_run_configuration(shipped, caplog) -> None:
    from semmap.config import InputConfig, OutputConfig, RunConfig, SemanticsConfig
    from semmap.factories import segmenter_for

    _manifest(shipped, "0" * 64)
    where = dict(input=InputConfig(dataset=shipped), output=OutputConfig(out=shipped.parent / "out"))
    config = RunConfig(**where, semantics=SemanticsConfig(segmenter="fcn"))
    assert config.semantics.trust_weights is False
    with pytest.raises(ConfigError, match="differs"):
        segmenter_for(config)
    trusting = RunConfig(**where, semantics=SemanticsConfig(segmenter="fcn", trust_weights=True))
    with caplog.at_level(logging.WARNING, logger="semmap"):
        assert segmenter_for(trusting) is not None
    assert "used anyway" in caplog.text


def test_the_run_command_offers_trust_weights() -> None:
    from typer.testing import CliRunner

    from semmap.cli import app

    r = CliRunner().invoke(app, ["run", "--help"], env={"COLUMNS": "200", "TERM": "dumb"})
    assert r.exit_code == 0 and "--trust-weights" in r.output


def test_unlisted_shipped_weights_are_refused_but_users_own_weights_are_not_checked(shipped, weights_file) -> None:
    (shipped / MANIFEST).write_text(json.dumps({"networks": {}}))
    with pytest.raises(ConfigError, match="not listed in"):
        make_segmenter("fcn")
    assert len(make_segmenter("fcn", weights=weights_file).label_set) == 7  # e.g. RUN/best.pt: not in a manifest


# ------------------------------------------------------------------ S9: NaN weights
@pytest.mark.parametrize("poison", [float("nan"), float("inf")])
def test_weights_holding_nan_or_inf_are_refused_naming_the_file(tmp_path, poison) -> None:
    path = _tiny_fcn(tmp_path / "nan_weights.pt", poison=poison)
    with pytest.raises(FormatError, match=r"nan_weights\.pt: weights hold NaN or infinite values") as e:
        load_weights(path)
    assert "\n" not in str(e.value)
    with pytest.raises(FormatError, match="NaN"):
        make_segmenter("fcn", weights=path)


# ------------------------------------------------------------------ hostile pickles: semmap's own line
def _hostile(path: Path, blob: dict | None = None) -> Path:
    torch.save({"format": "semmap-network", **(blob or {}), "payload": argparse.Namespace(cmd="id")}, path)
    return path


def _assert_refused_safely(exc: BaseException, path: Path) -> None:
    text = str(exc)
    assert str(path) in text and "refused" in text and "\n" not in text
    assert "weights_only" not in text and "arbitrary code" not in text.lower()


def test_a_hostile_pickle_is_refused_by_every_loader_in_semmaps_own_words(tmp_path) -> None:
    from semmap.perception.espnetv2 import load_espnetv2
    from semmap.perception.instances.maskrcnn import MaskRcnnInstances

    path = _hostile(tmp_path / "evil.pt")
    with pytest.raises(FormatError) as e:
        load_weights(path)
    _assert_refused_safely(e.value, path)
    with pytest.raises(FormatError) as e:
        load_espnetv2(path)
    _assert_refused_safely(e.value, path)
    with pytest.raises(ConfigError) as e:
        MaskRcnnInstances.from_weights(path)
    _assert_refused_safely(e.value, path)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(FormatError, match=r"junk\.pt: cannot read this network weights file \(not a PyTorch") as e:
        load_weights(junk)
    assert "weights_only" not in str(e.value) and "\n" not in str(e.value)


@pytest.mark.slow
def test_a_hostile_training_checkpoint_is_refused_on_resume(tmp_path) -> None:
    from semmap.train.trainer import Trainer
    from test_train import settings, write_plain

    data = write_plain(tmp_path / "data")
    s = settings(tmp_path, data)
    s.out.mkdir(parents=True)
    path = _hostile(s.out / "last.pt")
    with pytest.raises(FormatError) as e:
        Trainer(s, resume=True)
    _assert_refused_safely(e.value, path)


def test_nan_in_espnetv2_and_maskrcnn_weights_is_refused(tmp_path) -> None:
    from semmap.perception.espnetv2 import load_espnetv2
    from semmap.perception.instances.maskrcnn import MaskRcnnInstances

    path = tmp_path / "nan.pth"
    torch.save({"level1.conv.weight": torch.full((3, 3), float("nan")),
                "roi_heads.box_predictor.cls_score.weight": torch.full((2, 4), float("nan"))}, path)
    with pytest.raises(FormatError, match=r"nan\.pth: weights hold NaN"):
        load_espnetv2(path)
    with pytest.raises(ConfigError, match=r"nan\.pth: weights hold NaN"):
        MaskRcnnInstances.from_weights(path)


# ------------------------------------------------------------------ a network that outputs NaN
class _NanNet(torch.nn.Module):
    """Logits of NaN on a quarter-resolution grid (a diverged network)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, _, h, w = x.shape
        return torch.full((n, 7, h // 4, w // 4), float("nan"))


def test_a_network_that_outputs_nan_stops_the_run_naming_the_frame() -> None:
    from semmap.perception.network import NetworkInput, NetworkSegmenter

    frames = make_room_frames(2)
    seg = NetworkSegmenter(_NanNet(), room_label_set(), name="nan-net", net_input=NetworkInput(size=(80, 64)),
                           batch_size=2)
    with pytest.raises(ConfigError, match=rf"nan-net: the network output NaN .* frame {frames[0].name}") as e:
        seg.segment_batch(frames)
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="image 0"):
        seg.predict(frames[0].rgb)


# ------------------------------------------------------------------ S11-S13: precomputed predictions
def _probs(h: int, w: int, k: int) -> np.ndarray:
    p = np.full((h, w, k), 0.5 / (k - 1), np.float32)
    p[..., 1] = 0.5
    return p


def test_precomputed_predictions_with_nan_are_refused_naming_the_file(tmp_path) -> None:
    from semmap.perception.precomputed import PrecomputedSegmenter

    frame = make_room_frames(1)[0]
    h, w = frame.depth.shape
    probs = _probs(h, w, 7)
    probs[: h // 2] = np.nan  # half NaN
    np.save(tmp_path / f"{frame.name}.npy", probs)
    with pytest.raises(FormatError, match=rf"{frame.name}\.npy: probabilities hold NaN") as e:
        PrecomputedSegmenter(tmp_path, label_set=room_label_set()).segment(frame)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("size", [(10, 64), (60, 60), (30, 80)])
def test_precomputed_predictions_of_another_shape_are_refused(tmp_path, size) -> None:
    from semmap.perception.precomputed import PrecomputedSegmenter

    frame = make_room_frames(1)[0]
    np.save(tmp_path / f"{frame.name}.npy", _probs(*size, 7))
    with pytest.raises(FormatError, match=rf"{frame.name}\.npy: prediction is {size[1]}x{size[0]} but frame"):
        PrecomputedSegmenter(tmp_path, label_set=room_label_set()).segment(frame)
    np.save(tmp_path / f"{frame.name}.npy", _probs(30, 40, 7))  # the network's half-resolution grid: resized
    top = PrecomputedSegmenter(tmp_path, label_set=room_label_set()).segment(frame)
    assert top.labels.shape[:2] == frame.depth.shape and (top.labels[..., 0] == 1).all()


def test_precomputed_png_labels_of_another_shape_are_refused(tmp_path) -> None:
    from helpers import write_png
    from semmap.perception.precomputed import PrecomputedSegmenter

    frame = make_room_frames(1)[0]
    write_png(tmp_path / f"{frame.name}.png", np.ones((10, 64), np.uint16))
    with pytest.raises(FormatError, match="prediction is 64x10"):
        PrecomputedSegmenter(tmp_path, label_set=room_label_set()).segment(frame)


def test_precomputed_predictions_of_another_class_count_than_the_dataset_are_refused(tmp_path) -> None:
    frame = make_room_frames(1)[0]
    np.save(tmp_path / f"{frame.name}.npy", _probs(*frame.depth.shape, 4))  # K=4, the dataset has 7 classes
    seg = make_segmenter("precomputed", weights=tmp_path, label_set=room_label_set())
    with pytest.raises(FormatError, match=r"expected \(H, W, 7\) for the 7 classes"):
        seg.segment(frame)
    assert len(make_segmenter("precomputed", weights=tmp_path).label_set) == 4  # no dataset classes: the file's
    labels = room_label_set()
    (tmp_path / "labelset.json").write_text(json.dumps(type(labels)(labels.names[:4], labels.colors[:4]).to_dict()))
    seg = make_segmenter("precomputed", weights=tmp_path, label_set=labels)  # the folder's own classes win
    assert len(seg.label_set) == 4 and seg.segment(frame) is not None


# ------------------------------------------------------------------ depth of an implausible unit
@pytest.mark.parametrize(("read_scale", "likely"), [(1.0, "5000"), (5000.0 * 1000, "5000")])
def test_depth_implausible_for_its_unit_warns_once_with_the_likely_scale(tmp_path, caplog, read_scale,
                                                                          likely) -> None:
    from semmap.datasets.tum import TumDataset
    from semmap.io.tum_writer import write_tum_sequence

    root = tmp_path / "seq"
    write_tum_sequence(root, make_room_frames(3), depth_scale=5000.0)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        frames = list(TumDataset(root, depth_scale=read_scale))
    assert len(frames) == 3
    warnings = [r.getMessage() for r in caplog.records if "implausible" in r.getMessage()]
    assert len(warnings) == 1 and f"--depth-scale {likely}" in warnings[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="semmap"):
        assert len(list(TumDataset(root))) == 3  # the right scale: no warning
    assert "implausible" not in caplog.text


# ------------------------------------------------------------------ S7, S8, T34: localize's numbers
@pytest.mark.parametrize("field", ["height", "pitch_deg", "roll_deg", "motion_noise"])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_localize_options_refuse_nan_and_inf(field, value) -> None:
    from semmap.localization.sequence import LocalizeOptions

    option = "--" + field.replace("_", "-")
    with pytest.raises(ConfigError, match=f"{option} must be a finite number"):
        LocalizeOptions(**{field: value})


def test_localize_options_refuse_bad_counts_and_poses() -> None:
    from semmap.localization.filter import FilterSettings
    from semmap.localization.sequence import LocalizeOptions
    from semmap.types import pose_from_tum

    with pytest.raises(ConfigError, match="--points"):
        LocalizeOptions(points=0)
    with pytest.raises(ConfigError, match="--particles"):
        LocalizeOptions(settings=FilterSettings(particles=float("nan")))
    for pose in ([float("nan"), 0, 0, 0, 0, 0, 1], [0] * 7, [0, 0, float("inf"), 0, 0, 0, 1]):
        with np.errstate(invalid="ignore"), pytest.raises(ConfigError, match="--init-pose"):
            LocalizeOptions(init_pose=pose_from_tum(pose))
    with pytest.raises(ConfigError, match="not a proper rotation"):
        LocalizeOptions(init_pose=np.diag([2.0, 1.0, 1.0, 1.0]))
    assert LocalizeOptions(init_pose=pose_from_tum([1, 2, 0, 0, 0, 0, 2]), height=1.2).height == 1.2


@pytest.fixture(scope="module")
def room_map(tmp_path_factory) -> tuple[Path, Path]:
    """map.semmap of a few room frames, and the room sequence as a TUM folder."""
    from semmap.geometry import backproject_world
    from semmap.io.native import save_map
    from semmap.io.tum_writer import write_tum_sequence
    from semmap.maps.semantic_octomap import SemanticOctoMap
    from semmap.types import TopKProbs

    root = tmp_path_factory.mktemp("room")
    frames = make_room_frames(4)
    m = SemanticOctoMap(0.1, label_set=room_label_set())
    for f in frames:
        pts, pix = backproject_world(f.depth, f.intrinsics, f.T_world_cam)
        flat = TopKProbs.from_hard_labels(f.labels, 0.9, 7).reshape_flat()
        m.insert_points(pts, f.T_world_cam[:3, 3], semantics=TopKProbs(flat.labels[pix], flat.probs[pix]))
    save_map(root / "map.semmap", m)
    write_tum_sequence(root / "seq", frames, label_set=room_label_set())
    return root / "map.semmap", root / "seq"


@pytest.mark.slow
@pytest.mark.parametrize(("args", "message"), [
    (["--mode", "ground", "--height", "nan"], "--height must be a finite number"),  # T34: was SIGSEGV
    (["--init", "tracking", "--init-pose", "nan 0 0 0 0 0 1"], "--init-pose must be 7 finite numbers"),  # S7
])
def test_the_localize_command_refuses_nan_in_one_line(room_map, tmp_path, args, message) -> None:
    map_path, seq = room_map
    r = subprocess.run([sys.executable, "-m", "semmap.cli", "localize", str(map_path), str(seq), "--max-frames", "2",
                        "--out", str(tmp_path / "o"), *args], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, (r.returncode, r.stderr)  # an error, not a segfault (139) nor a traceback
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()
