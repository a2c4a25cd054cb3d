"""Pretrained starts (``semmap train --init``): the ESPNetv2 encoder under the papers' heads (loaded / new summary,
CBAM and depth fusion leaving the pretrained function unchanged at step 0, shapes), torchvision's layouts
(random weights, no download) and its offline message; temperature scaling (fit, ECE, the segmenter)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from semmap.errors import ConfigError, SemmapError
from semmap.perception.calibration import apply_temperature
from semmap.perception.espnetv2 import ESPNetv2Seg
from semmap.perception.networks import pretrained
from semmap.perception.networks.registry import MODELS, NetworkSpec, build_network, save_weights
from semmap.train.calibrate import expected_calibration_error, fit_temperature, nll
from semmap.types import LabelSet

#: torchvision is the optional extra semmap[maskrcnn]: its tests run where it is installed.
NEEDS_TORCHVISION = pytest.mark.skipif(importlib.util.find_spec("torchvision") is None,
                                       reason="torchvision is not installed (pip install 'semmap[maskrcnn]')")

K = 5
BACKBONE = "espnetv2-s1"


def espnet_spec(model: str) -> NetworkSpec:
    return NetworkSpec(model, K, width=0.125, depth=18, backbone=BACKBONE, msff_dilation=2)


@pytest.fixture(scope="module")
def pascal_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding a (randomly initialised) ESPNetv2 s=1 PASCAL state dict under the published file name."""
    torch.manual_seed(3)
    net = ESPNetv2Seg(1.0, 21)
    for m in net.modules():  # non-trivial BN statistics, so that copying them is visible
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2)
            m.running_var.uniform_(0.5, 2.0)
    folder = tmp_path_factory.mktemp("pascal")
    torch.save(net.state_dict(), folder / pretrained.ESPNET_FILES[BACKBONE])
    return folder


@pytest.fixture
def with_pascal(pascal_dir: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv(pretrained.PRETRAINED_ENV, str(pascal_dir))
    return pascal_dir


def loaded(model: str) -> tuple[torch.nn.Module, pretrained.LoadSummary]:
    torch.manual_seed(0)
    net = build_network(espnet_spec(model))
    return net, pretrained.load_pretrained(net, "espnetv2-pascal-s1")


def test_summary_counts_loaded_and_new_layers(with_pascal: Path) -> None:
    net, summary = loaded("pspnet")
    file_sd = torch.load(with_pascal / pretrained.ESPNET_FILES[BACKBONE], weights_only=True)
    encoder = [k for k in file_sd if k.startswith("base_net.")]
    assert len(summary.loaded) == len(encoder) == 361  # every encoder tensor, nothing of the PASCAL decoder
    assert len(summary.unused) == len(file_sd) - len(encoder)
    assert set(summary.new) == {k for k in net.state_dict() if not k.startswith("backbone.encoder.")}
    assert len(summary.layers(summary.loaded)) == 177 and len(summary.layers(summary.new)) == 14
    text = summary.text()
    assert "loaded 361 tensors (177 layers)" in text and "ppm, head, aux" in text
    sd = net.state_dict()
    for k in ("base_net.level1.conv.weight", "base_net.level4.6.br_after_cat.bn.running_var"):
        assert torch.equal(sd["backbone.encoder." + k.removeprefix("base_net.")], file_sd[k])


def test_rgbd_net_loads_the_colour_encoder(with_pascal: Path) -> None:
    _, summary = loaded("rgbd-net")
    assert len(summary.loaded) == 361
    assert all(k.startswith("color.encoder.") for k in summary.loaded)
    assert {k.split(".")[0] for k in summary.new} == {"depth", "fuse", "fusion", "classifier"}


def test_missing_pascal_file_and_unknown_init_are_one_line_errors(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(pretrained.PRETRAINED_ENV, str(tmp_path))
    net = build_network(espnet_spec("fcn"))
    with pytest.raises(ConfigError, match="not found") as err:
        pretrained.load_pretrained(net, "espnetv2-pascal-s1")
    assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match="choose from espnetv2-pascal"):
        pretrained.init_plan("imagenet")
    from semmap.train.trainer import TrainSettings

    with pytest.raises(ConfigError, match="--model pspnet has no vgg16 backbone"):
        TrainSettings(model="pspnet", data=(tmp_path,), out=tmp_path / "o", init="torchvision:vgg16").with_init()
    s = TrainSettings(model="rgb-only", data=(tmp_path,), out=tmp_path / "o", init="torchvision:vgg16").with_init()
    assert (s.backbone, s.width) == ("vgg16", 1.0)


def test_cbam_is_the_identity_at_step_zero(with_pascal: Path) -> None:
    plain, _ = loaded("pspnet")
    cbam, summary = loaded("cbam-pspnet")
    assert any(k.startswith("backbone.attention.") for k in summary.new)
    x = torch.randn(2, 3, 48, 64, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        a = plain.eval().backbone(x)
        b = cbam.eval().backbone(x)
        for fa, fb in zip(a, b, strict=True):
            assert torch.equal(fa, fb)
        for gate in cbam.backbone.attention:  # open the gates: the paper's CBAM, a different function
            gate.gate.fill_(1.0)
        assert not torch.allclose(cbam.backbone(x)[3], a[3])


def test_depth_enters_through_zero_projections(with_pascal: Path) -> None:
    rgbd, _ = loaded("rgbd-net")
    colour, _ = loaded("rgb-only")
    colour.load_state_dict({k: v for k, v in rgbd.state_dict().items() if k in colour.state_dict()})
    g = torch.Generator().manual_seed(2)
    x, d = torch.randn(1, 3, 48, 64, generator=g), 0.5 + 4 * torch.rand(1, 1, 48, 64, generator=g)
    with torch.no_grad():
        assert torch.equal(rgbd.eval()(x, d), colour.eval()(x))  # step 0: the colour-only twin
        for conv in rgbd.fuse:
            conv.weight.normal_()
        assert not torch.allclose(rgbd(x, d), colour(x))
    with pytest.raises(ValueError, match="needs a depth image"):
        rgbd(x)


@pytest.mark.parametrize("model", list(MODELS))
def test_every_architecture_on_the_espnet_encoder(model: str) -> None:
    torch.manual_seed(0)
    net = build_network(espnet_spec(model)).eval()
    g = torch.Generator().manual_seed(1)
    x, d = torch.randn(2, 3, 50, 66, generator=g), 4 * torch.rand(2, 1, 50, 66, generator=g)
    args = (x, d) if MODELS[model].uses_depth else (x,)
    stride = 4 if model == "fcn" else 16
    with torch.no_grad():
        out = net(*args)
    assert out.shape == (2, K, -(-50 // stride), -(-66 // stride))
    net.train()
    main, aux = net.forward_train(*args)
    assert main.shape == (2, K, 50, 66)
    assert (aux is not None) == (model in ("pspnet", "cbam-pspnet"))
    assert espnet_spec(model).describe() == f"{model}-{BACKBONE}-w0.125"


@pytest.mark.slow
@NEEDS_TORCHVISION
def test_torchvision_resnet_and_vgg_layouts_load_without_download() -> None:
    from semmap.perception.instances._torchvision_ops import import_torchvision

    tv = import_torchvision()
    torch.manual_seed(0)
    resnet = tv.models.resnet18(weights=None).eval()
    net = build_network(NetworkSpec("pspnet", K, width=1.0, depth=18))
    summary = pretrained.load_torchvision(net, "torchvision:resnet18", resnet.state_dict())
    assert summary.unused == ("fc.weight", "fc.bias")
    assert all(k.startswith(("ppm.", "head.", "aux.")) for k in summary.new)
    assert torch.equal(net.state_dict()["backbone.layer2.0.shortcut.0.weight"], resnet.layer2[0].downsample[0].weight)
    vgg = tv.models.vgg16(weights=None).eval()
    colour = build_network(NetworkSpec("rgb-only", K, width=1.0, msff_dilation=2)).eval()
    summary = pretrained.load_torchvision(colour, "torchvision:vgg16", vgg.state_dict())
    assert len(summary.loaded) == 13 * 5 and all(k.startswith("classifier.") for k in summary.unused)
    x = torch.randn(1, 3, 32, 32)
    with torch.no_grad():  # conv bias carried by the BN after it: block 1 computes what VGG's did
        torch.testing.assert_close(colour.color[0](x), vgg.features[:4](x), atol=1e-4, rtol=1e-4)


@NEEDS_TORCHVISION
def test_offline_torchvision_says_so_in_one_line(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from urllib.error import URLError

    from semmap.perception.instances._torchvision_ops import import_torchvision

    import_torchvision()
    import torchvision.models._api as api

    def offline(*_a, **_k):
        raise URLError("[Errno -3] Temporary failure in name resolution")

    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setattr(api, "load_state_dict_from_url", offline, raising=False)
    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", offline)
    net = build_network(NetworkSpec("pspnet", K, width=1.0, depth=50))
    with pytest.raises(ConfigError, match="cannot download torchvision's ImageNet weights") as err:
        pretrained.load_pretrained(net, "torchvision:resnet50")
    assert "\n" not in str(err.value) and "offline" in str(err.value)



@pytest.mark.slow
@pytest.mark.parametrize("model", ["cbam-pspnet", "rgbd-net"])
def test_onnx_export_of_the_espnet_heads_agrees_with_pytorch(model: str, tmp_path: Path) -> None:
    import onnxruntime as ort

    from semmap.perception.network import export_onnx

    torch.manual_seed(0)
    net = build_network(espnet_spec(model)).eval()
    with torch.no_grad():  # open the zero-initialised gates / projections so that every branch counts
        for name, p in net.named_parameters():
            if name.endswith(".gate") or name.startswith("fuse."):
                p.normal_(0.0, 0.5)
    g = torch.Generator().manual_seed(4)
    x, d = torch.randn(1, 3, 60, 80, generator=g), 4 * torch.rand(1, 1, 60, 80, generator=g)
    depth = MODELS[model].uses_depth
    path = export_onnx(net, tmp_path / f"{model}.onnx", tuple(x.shape), with_depth=depth)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = sess.run(None, {"image": x.numpy()} | ({"depth": d.numpy()} if depth else {}))[0]
    with torch.no_grad():
        ref = net(x, d if depth else None).numpy()
    np.testing.assert_allclose(got, ref, rtol=1e-3, atol=1e-3)

# ----------------------------------------------------------------------------------------------- calibration
def test_temperature_fit_recovers_a_known_temperature() -> None:
    rng = np.random.default_rng(0)
    logits = rng.normal(0.0, 3.0, (20000, 8))
    true_t = 2.5
    p = np.exp(logits / true_t)
    p /= p.sum(axis=1, keepdims=True)
    labels = (p.cumsum(axis=1) < rng.random((len(p), 1))).sum(axis=1)  # labels drawn from softmax(logits / 2.5)
    t = fit_temperature(logits, labels)
    assert abs(t - true_t) / true_t < 0.05
    assert nll(logits, labels, t) < nll(logits, labels, 1.0)


def test_apply_temperature_is_softmax_of_scaled_logits_and_ece_counts_gaps() -> None:
    logits = np.random.default_rng(1).normal(size=(4, 6, 7))
    p = np.exp(logits) / np.exp(logits).sum(-1, keepdims=True)
    q = np.exp(logits / 3.0) / np.exp(logits / 3.0).sum(-1, keepdims=True)
    np.testing.assert_allclose(apply_temperature(p, 3.0), q, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(apply_temperature(p, 1.0), p)
    with pytest.raises(SemmapError, match="temperature"):
        apply_temperature(p, 0.0)
    # confidence 0.9 everywhere, right 60 % of the time: ECE 0.3; perfectly calibrated: 0
    assert expected_calibration_error(np.full(10, 0.9), np.arange(10) < 6) == pytest.approx(0.3)
    assert expected_calibration_error(np.full(10, 0.6), np.arange(10) < 6) == pytest.approx(0.0)


def test_segmenter_applies_the_stored_temperature_unless_turned_off(tmp_path: Path) -> None:
    from semmap.perception.registry import make_segmenter

    torch.manual_seed(0)
    spec = NetworkSpec("fcn", K, width=0.125, depth=18)
    labels = LabelSet(tuple(f"c{i}" for i in range(K)), np.arange(3 * K).reshape(K, 3))
    path = save_weights(tmp_path / "fcn.pt", build_network(spec), spec, labels, (64, 48), {"temperature": 4.0})
    rgb = np.random.default_rng(0).integers(0, 255, (48, 64, 3), np.uint8)
    hot = make_segmenter("fcn", weights=path)
    cold = make_segmenter("fcn", weights=path, calibration=False)
    assert hot.temperature == 4.0 and cold.temperature == 1.0
    p_hot, p_cold = hot.probabilities(rgb).astype(np.float32), cold.probabilities(rgb).astype(np.float32)
    assert (p_hot.argmax(-1) == p_cold.argmax(-1)).mean() > 0.99  # same ranking, flatter distribution
    assert p_hot.max(-1).mean() < p_cold.max(-1).mean()


def test_training_from_a_pretrained_start_stores_init_and_temperature(with_pascal: Path, tmp_path: Path) -> None:
    from semmap.perception.networks.registry import load_weights
    from semmap.train.trainer import Trainer
    from test_train import settings, write_plain

    data = write_plain(tmp_path / "data")
    trainer = Trainer(settings(tmp_path, data, init="espnetv2-pascal-s1", iterations=1))
    assert trainer.spec.backbone == BACKBONE and trainer.init_summary is not None
    assert len(trainer.init_summary.loaded) == 361
    result = trainer.run()
    best = load_weights(result.best)
    assert best.meta["init"] == "espnetv2-pascal-s1" and best.spec.describe().startswith("pspnet-espnetv2-s1")
    assert best.meta["temperature"] == result.rows[-1]["val_temperature"] > 0
    assert {"val_nll", "val_nll_calibrated", "val_ece", "val_ece_calibrated"} <= set(result.rows[-1])
    assert result.rows[-1]["val_nll_calibrated"] <= result.rows[-1]["val_nll"]


def test_calibrate_weights_writes_a_copy_with_its_temperature(tmp_path: Path) -> None:
    from semmap.errors import SemmapError
    from semmap.perception.networks.registry import load_weights
    from semmap.train.calibrate import calibrate_weights
    from test_train import write_plain

    data = write_plain(tmp_path / "data", n=3)
    spec = NetworkSpec("fcn", 4, width=0.125, depth=18)
    torch.manual_seed(0)
    src = save_weights(tmp_path / "fcn.pt", build_network(spec), spec, LabelSet.generic(4), (32, 24), {})
    record = calibrate_weights(src, [data], tmp_path / "cal.pt", pixel_step=2)
    cal = load_weights(tmp_path / "cal.pt")
    assert cal.meta["temperature"] == record["temperature"] > 0 and record["nll_calibrated"] <= record["nll"]
    assert "temperature" not in load_weights(src).meta
    with pytest.raises(SemmapError):  # the input is never an output
        calibrate_weights(src, [data], src)


@pytest.mark.slow
def test_calibrate_weights_on_rendered_validation_scenes_writes_the_fitted_temperature(tmp_path: Path) -> None:
    """``calibrate_weights.py --scenes``: the temperature is fitted on validation scenes rendered as `semmap run`
    meets frames (through the segmenter), and the copy carries it with the record of where it was fitted."""
    from script_modules import load_script
    from semmap.labels import INDOOR_LABELS
    from semmap.perception.networks.registry import load_weights

    script = load_script("scripts/calibrate_weights.py")
    spec = NetworkSpec("fcn", len(INDOOR_LABELS), width=0.125, depth=18)
    torch.manual_seed(0)
    src = save_weights(tmp_path / "fcn.pt", build_network(spec), spec, INDOOR_LABELS, (32, 24), {})
    record = script.calibrate_on_scenes(src, tmp_path / "cal.pt", scenes=1, every=300, threads=1)
    cal = load_weights(tmp_path / "cal.pt")
    assert cal.meta["temperature"] == record["temperature"] > 0
    assert record["images"] == 1 and record["nll_calibrated"] <= record["nll"] + 1e-9
    assert record["fitted_on"].startswith("validation scenes 300-300")
    with pytest.raises(SemmapError):  # the input is never an output
        script.calibrate_on_scenes(src, src, scenes=1, every=300)
