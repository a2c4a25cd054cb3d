"""The papers' segmentation networks: shapes, the papers' structure (CBAM eqs. 1-2, PSPNet bins, the RGB-D
branches), full sizes constructible, ONNX export agreeing with PyTorch, weight files and the segmenter."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F  # noqa: N812
from hypothesis import given, settings
from hypothesis import strategies as st

from helpers import make_room_frames
from semmap.errors import ConfigError, FormatError
from semmap.perception.network import export_onnx
from semmap.perception.networks.cbam import CBAM
from semmap.perception.networks.layers import adaptive_avg_pool
from semmap.perception.networks.registry import (
    MODELS,
    NetworkSpec,
    build_network,
    count_parameters,
    load_weights,
    save_weights,
)
from semmap.perception.networks.resnet import ResNet
from semmap.perception.registry import make_segmenter
from semmap.types import LabelSet

K = 6
SMALL = {"width": 0.125, "depth": 18, "msff_dilation": 2}


def small(model: str) -> torch.nn.Module:
    torch.manual_seed(0)
    return build_network(NetworkSpec(model, K, **SMALL)).eval()


def inputs(model: str, h: int = 48, w: int = 64, n: int = 2) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(1)
    x = torch.randn(n, 3, h, w, generator=g)
    return (x, 0.5 + 4 * torch.rand(n, 1, h, w, generator=g)) if model == "rgbd-net" else (x,)


@pytest.mark.parametrize("model", list(MODELS))
def test_logits_at_output_stride_and_training_outputs_at_input_size(model: str) -> None:
    net = small(model)
    stride = 16 if model in ("rgbd-net", "rgb-only") else 8
    with torch.no_grad():
        out = net(*inputs(model))
    assert out.shape == (2, K, 48 // stride, 64 // stride)
    net.train()
    main, aux = net.forward_train(*inputs(model))
    assert main.shape == (2, K, 48, 64)
    assert (aux is not None) == (model in ("pspnet", "cbam-pspnet"))  # PSPNet's auxiliary head, training only
    if aux is not None:
        assert aux.shape == main.shape


def test_full_resolution_forward_matches_input_size() -> None:
    net = build_network(NetworkSpec("fcn", K, **SMALL), full_resolution=True).eval()
    with torch.no_grad():
        assert net(torch.zeros(1, 3, 40, 56)).shape == (1, K, 40, 56)  # not a multiple of 32: skips still fuse


@pytest.mark.slow
@pytest.mark.parametrize("model,depth", [("pspnet", 50), ("cbam-pspnet", 50), ("fcn", 50), ("rgbd-net", 0)])
def test_the_papers_full_sizes_build_and_run(model: str, depth: int) -> None:
    net = build_network(NetworkSpec(model, 150, width=1.0, depth=depth or 50)).eval()
    x = inputs(model, 32, 32, 1)
    with torch.no_grad():
        assert net(*x).shape[:2] == (1, 150)
    n = count_parameters(net)
    assert n > 14e6  # VGG-16 convolutions alone hold 14.7 M, ResNet-50 23.5 M


def test_resnet50_backbone_has_the_standard_parameter_count() -> None:
    assert abs(count_parameters(ResNet(50)) - 23.51e6) < 0.02e6
    assert abs(count_parameters(ResNet(18)) - 11.18e6) < 0.02e6


def test_fcn_vgg16_backbone_builds() -> None:
    net = build_network(NetworkSpec("fcn", K, backbone="vgg16", width=0.125)).eval()
    with torch.no_grad():
        assert net(torch.zeros(1, 3, 48, 64)).shape == (1, K, 6, 8)


def test_cbam_follows_eqs_1_and_2() -> None:
    torch.manual_seed(3)
    cbam = CBAM(32).eval()
    x = torch.randn(2, 32, 9, 11)
    w0, w1 = cbam.channel.mlp[0].weight[:, :, 0, 0], cbam.channel.mlp[2].weight[:, :, 0, 0]

    def mlp(v):
        return torch.relu(v @ w0.T) @ w1.T

    mc = torch.sigmoid(mlp(x.mean((2, 3))) + mlp(x.amax((2, 3))))  # eq. 1
    f1 = x * mc[:, :, None, None]
    desc = torch.stack([f1.mean(1), f1.amax(1)], 1)
    ms = torch.sigmoid(F.conv2d(desc, cbam.spatial.conv.weight, padding=3))  # eq. 2, 7x7
    with torch.no_grad():
        torch.testing.assert_close(cbam(x), f1 * ms)


def test_cbam_pspnet_is_pspnet_plus_attention_in_every_residual_block() -> None:
    psp, cbam = small("pspnet").state_dict(), small("cbam-pspnet").state_dict()
    extra = set(cbam) - set(psp)
    assert set(psp) <= set(cbam)  # the ResNet's structure is unchanged
    assert all(".attention." in k for k in extra)
    blocks = {k.split(".attention.")[0] for k in extra}
    assert len(blocks) == 8  # ResNet-18: 2 + 2 + 2 + 2 residual blocks, each with its own CBAM
    assert all(psp[k].shape == cbam[k].shape for k in psp)


def test_rgbd_net_uses_depth_and_its_twin_has_no_depth_branch() -> None:
    net = small("rgbd-net")
    x, d = inputs("rgbd-net")
    with torch.no_grad():
        assert not torch.allclose(net(x, d), net(x, d * 2))
    twin = small("rgb-only")
    assert not any(k.startswith("depth.") for k in twin.state_dict())
    depth_branch = [k for k in net.state_dict() if k.startswith("depth.")]
    assert len({k.split(".")[1] for k in depth_branch}) == 4  # conv1-conv4 only: conv5 removed in the sub-branch
    with pytest.raises(ValueError, match="needs a depth"):
        net(x)


@settings(max_examples=40, deadline=None)
@given(h=st.integers(1, 23), w=st.integers(1, 23), bins=st.sampled_from([1, 2, 3, 6]))
def test_matmul_adaptive_pooling_equals_torch(h: int, w: int, bins: int) -> None:
    x = torch.randn(1, 2, h, w, generator=torch.Generator().manual_seed(h * 31 + w))
    torch.testing.assert_close(adaptive_avg_pool(x, bins), F.adaptive_avg_pool2d(x, bins), rtol=1e-5, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("model", list(MODELS))
def test_onnx_export_agrees_with_pytorch(model: str, tmp_path) -> None:
    import onnxruntime as ort

    net = small(model)
    x = inputs(model, 60, 80, 1)  # 80x60: pyramid bins that do not divide the feature map
    path = export_onnx(net, tmp_path / f"{model}.onnx", tuple(x[0].shape), with_depth=model == "rgbd-net")
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    feeds = {"image": x[0].numpy()} | ({"depth": x[1].numpy()} if len(x) > 1 else {})
    got = sess.run(None, feeds)[0]
    with torch.no_grad():
        ref = net(*x).numpy()
    assert got.shape == ref.shape
    assert (got.argmax(1) == ref.argmax(1)).mean() >= 0.995
    np.testing.assert_allclose(got, ref, rtol=1e-3, atol=1e-3)


def test_weight_file_round_trip_and_errors(tmp_path) -> None:
    labels = LabelSet.generic(K)
    spec = NetworkSpec("cbam-pspnet", K, **SMALL)
    net = small("cbam-pspnet")
    path = save_weights(tmp_path / "w.pt", net, spec, labels, (64, 48), {"note": "test"})
    loaded = load_weights(path)
    assert loaded.spec == spec and loaded.label_set == labels and loaded.input_size == (64, 48)
    assert loaded.meta == {"note": "test"}
    x = inputs("cbam-pspnet", n=1)
    with torch.no_grad():  # float16 storage changes no prediction
        assert (loaded.model(*x).argmax(1) == net(*x).argmax(1)).float().mean() >= 0.995
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    with pytest.raises(FormatError, match=r"junk\.pt"):
        load_weights(tmp_path / "junk.pt")
    torch.save({"a": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(FormatError, match="not a semmap network"):
        load_weights(tmp_path / "other.pt")
    with pytest.raises(ConfigError, match="unknown network"):
        NetworkSpec("segnet", K)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["pspnet", "rgbd-net"])
@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_segmenter_runs_a_weight_file_on_frames(model: str, backend: str, tmp_path) -> None:
    frames = make_room_frames(2)
    labels = LabelSet.generic(K)
    path = save_weights(tmp_path / f"{model}.pt", small(model), NetworkSpec(model, K, **SMALL), labels, (64, 48))
    seg = make_segmenter(model, weights=path, backend=backend, batch_size=2)
    assert seg.label_set == labels and seg.name == model
    out = seg.segment_batch(frames)
    h, w = frames[0].depth.shape
    assert out[0].labels.shape == (h, w, 3) and (out[0].labels[..., 0] < K).all()
    with pytest.raises(ConfigError, match=f"holds a {model}"):
        make_segmenter("fcn", weights=path)


def test_missing_shipped_weights_say_how_to_get_them(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("SEMMAP_WEIGHTS", str(tmp_path))
    with pytest.raises(ConfigError, match="semmap train"):
        make_segmenter("cbam-pspnet")


@pytest.mark.slow
def test_a_mapping_run_segments_with_an_rgbd_network(tmp_path) -> None:
    from helpers import room_label_set
    from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
    from semmap.io.tum_writer import write_tum_sequence
    from semmap.pipeline import Pipeline

    labels = room_label_set()
    root = tmp_path / "room"
    write_tum_sequence(root, make_room_frames(3), label_set=labels)
    torch.manual_seed(0)
    spec = NetworkSpec("rgbd-net", len(labels), **SMALL)
    path = save_weights(tmp_path / "w.pt", build_network(spec).eval(), spec, labels, (64, 48))
    seg = make_segmenter("rgbd-net", weights=path)
    config = RunConfig(input=InputConfig(dataset=root), mapping=MappingConfig(resolution=0.2),
                       semantics=SemanticsConfig(segmenter="rgbd-net", weights=path),
                       output=OutputConfig(out=tmp_path / "out"))
    report = Pipeline(config, segmenter=seg).run().report
    assert report["segmenter"] == "rgbd-net" and report["frames_segmented"] == 3
    assert 0.0 <= report["rgbd-net_miou_2d"] <= 1.0


def test_shipped_weights_match_their_manifest() -> None:
    import hashlib
    import json

    from semmap.labels import INDOOR_LABELS
    from semmap.perception.registry import MANIFEST, TRAINED_NETWORKS, demo_network, shipped_weights_dir

    manifest_path = shipped_weights_dir() / MANIFEST
    if not manifest_path.is_file():
        pytest.skip("no shipped weights")
    manifest = json.loads(manifest_path.read_text())
    assert set(manifest["networks"]) == set(TRAINED_NETWORKS)
    total = 0
    for name, entry in manifest["networks"].items():
        data = (shipped_weights_dir() / entry["file"]).read_bytes()
        total += len(data)
        assert len(data) <= 10 * 1024 * 1024 and hashlib.sha256(data).hexdigest() == entry["sha256"], name
        loaded = load_weights(shipped_weights_dir() / entry["file"])
        assert loaded.spec.model == name and loaded.label_set == INDOOR_LABELS
        assert entry["command"].startswith(f"semmap train --model {name} ")
        assert not set(manifest["data"]["train"]["scene_seeds"]) & set(range(10))  # test scenes are seeds 0-9
    assert total <= 60 * 1024 * 1024
    assert demo_network() == manifest["demo"]["network"]
    # the demo's network is the rule's choice (scripts/ship_weights.py): the best test MIoU per ms on ONNX Runtime
    onnx = {n: e["test"]["onnx"] for n, e in manifest["networks"].items() if "onnx" in e.get("test", {})}
    assert manifest["demo"]["network"] == max(onnx, key=lambda n: onnx[n]["miou"] / onnx[n]["ms_per_frame"])
    assert manifest["demo"]["miou"] == onnx[manifest["demo"]["network"]]["miou"]


@pytest.mark.slow
def test_demo_segments_with_the_shipped_network(tmp_path) -> None:
    import json

    from helpers import run_cli
    from semmap.perception.registry import demo_network

    name = demo_network()
    if name is None:
        pytest.skip("no shipped weights")
    r = run_cli("demo", "--frames", "6", "--out", str(tmp_path / "demo"), "--resolution", "0.1")
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "demo" / "report.json").read_text())
    assert report["segmenter"] == name and report["frames_segmented"] == 6
    assert f"{name}_miou_2d" in report and "miou_3d" in report
    assert f"## The network alone ({name})" in (tmp_path / "demo" / "report.md").read_text()
