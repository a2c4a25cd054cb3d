"""ESPNetv2 segmentation network: architecture vs. the published PASCAL VOC state dicts, loader errors, VOC labels."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from semmap.errors import FormatError
from semmap.perception.espnetv2 import (
    ESPNetv2Seg,
    eesp_dilations,
    espnetv2_channels,
    infer_width_multiplier,
    load_espnetv2,
)
from semmap.perception.voc import PASCAL_VOC

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "espnetv2"
FRAMES = SHARED / "data" / "7scenes-redkitchen"

#: Key patterns of the published state dicts (526 tensors, BN buffers included).
KEY_PATTERN = re.compile(
    r"^(base_net\.(level1|level[234]_0\.(eesp|inp_reinf\.[01]|act)|level[34]\.\d+)"
    r"|bu_dec_l[1-4]|merge_enc_dec_l[2-4]|bu_br_l[2-4])\..+$"
)


def _weights(s: str) -> Path:
    path = WEIGHTS / f"espnetv2_s_{s}_pascal_384x384.pth"
    if not path.is_file():
        pytest.skip(f"{path} is not present")
    return path


@pytest.fixture(scope="module")
def model_s1() -> ESPNetv2Seg:
    return load_espnetv2(_weights("1.0"))


# --------------------------------------------------------------------------------------------------
# No weights needed
# --------------------------------------------------------------------------------------------------
def test_random_model_builds_runs_and_names_match_published_layout() -> None:
    torch.manual_seed(0)
    model = ESPNetv2Seg(s=1.0).eval()
    sd = model.state_dict()
    assert len(sd) == 526
    assert all(KEY_PATTERN.match(k) for k in sd), [k for k in sd if not KEY_PATTERN.match(k)][:5]
    assert sd["base_net.level2_0.eesp.proj_1x1.conv.weight"].shape == (8, 8, 1, 1)  # grouped K=4
    assert sd["base_net.level4.6.conv_1x1_exp.conv.weight"].shape == (256, 64, 1, 1)
    assert sd["base_net.level4_0.inp_reinf.1.conv.weight"].shape == (256, 3, 1, 1)
    assert sd["merge_enc_dec_l2.expansion_layer.cbr.0.weight"].shape == (64, 2, 3, 3)
    assert sd["bu_dec_l1.merge_layer.2.cbr.0.weight"].shape == (10, 5, 3, 3)
    assert sd["bu_dec_l4.merge_layer.3.bias"].shape == (21,)
    assert "bu_dec_l4.br.br.0.weight" not in sd
    with torch.no_grad():
        out = model(torch.randn(1, 3, 72, 100))  # not a multiple of 16 on either side
    assert out.shape == (1, 21, 72, 100)
    assert torch.isfinite(out).all()


def test_width_config_and_dilations() -> None:
    assert espnetv2_channels(1.0) == (32, 64, 128, 256)
    assert espnetv2_channels(2.0) == (32, 128, 256, 512)
    assert espnetv2_channels(0.5) == (16, 32, 64, 128)
    assert eesp_dilations(13) == eesp_dilations(9) == (1, 2, 3, 4)
    assert eesp_dilations(7) == (1, 1, 2, 3)
    model = ESPNetv2Seg(s=2.0)
    assert model.base_net.level3[0].spp_dw[3].conv.dilation == (4, 4)
    assert [b.conv.dilation[0] for b in model.base_net.level4[0].spp_dw] == [1, 1, 2, 3]


def test_loader_round_trips_a_saved_state_dict_and_infers_s(tmp_path: Path) -> None:
    path = tmp_path / "whatever.pth"
    torch.save(ESPNetv2Seg(s=0.5).state_dict(), path)
    model = load_espnetv2(path)
    assert model.s == 0.5 and model.channels == (16, 32, 64, 128)
    assert not model.training
    assert infer_width_multiplier({}, "espnetv2_s_1.5_pascal_384x384.pth") == 1.5


def test_bad_files_raise_format_error_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="not found"):
        load_espnetv2(tmp_path / "missing.pth")
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"definitely not a torch file")
    with pytest.raises(FormatError, match=r"junk\.pth"):
        load_espnetv2(junk)
    notdict = tmp_path / "list.pth"
    torch.save([torch.zeros(3)], notdict)
    with pytest.raises(FormatError, match="state dict"):
        load_espnetv2(notdict)
    sd = ESPNetv2Seg(s=1.0).state_dict()
    del sd["base_net.level4.6.module_act.weight"]
    sd["extra.weight"] = torch.zeros(1)
    broken = tmp_path / "espnetv2_s_1.0_broken.pth"
    torch.save(sd, broken)
    missing_then_unexpected = r"missing keys: base_net\.level4\.6\.module_act\.weight.*unexpected keys: extra"
    with pytest.raises(FormatError, match=missing_then_unexpected):
        load_espnetv2(broken)
    sd = ESPNetv2Seg(s=1.0).state_dict()
    sd["bu_dec_l1.stages.0.weight"] = torch.zeros(10, 1, 5, 5)
    torch.save(sd, broken)
    with pytest.raises(FormatError, match=r"bu_dec_l1\.stages\.0\.weight"):
        load_espnetv2(broken)


def test_voc_label_set() -> None:
    assert len(PASCAL_VOC) == 21
    assert PASCAL_VOC.names[0] == "background"
    assert PASCAL_VOC.id_of("chair") == 9 and PASCAL_VOC.id_of("tvmonitor") == 20
    assert not np.all(PASCAL_VOC.colors == 255, axis=1).any()
    assert tuple(PASCAL_VOC.colors[15]) == (192, 128, 128)  # person, standard VOC palette
    assert len({tuple(c) for c in PASCAL_VOC.colors}) == 21


# --------------------------------------------------------------------------------------------------
# Published weights (skipped when ../shared is absent)
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("s", "channels"), [("1.0", (32, 64, 128, 256)), ("2.0", (32, 128, 256, 512))])
def test_published_weights_load_strictly(s: str, channels: tuple[int, ...]) -> None:
    path = _weights(s)
    model = load_espnetv2(path)
    assert model.s == float(s) and model.channels == channels
    published = torch.load(path, map_location="cpu", weights_only=True)
    assert set(model.state_dict()) == set(published)
    with torch.no_grad():
        out = model(torch.zeros(1, 3, 384, 384))
    assert out.shape == (1, 21, 384, 384)


def test_output_shape_non_square(model_s1: ESPNetv2Seg) -> None:
    with torch.no_grad():
        out = model_s1(torch.randn(1, 3, 200, 264))
    assert out.shape == (1, 21, 200, 264)


def test_half_resolution_logits_give_the_same_segmentation(model_s1: ESPNetv2Seg) -> None:
    """Skipping the network's last upsampling (the segmenter samples once, to the image) changes no decision."""
    from semmap.perception.network import NetworkInput, NetworkSegmenter
    from semmap.perception.voc import PASCAL_VOC

    rgb = np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    half = ESPNetv2Seg(model_s1.s, channels=model_s1.channels, full_resolution=False).eval()
    half.load_state_dict(model_s1.state_dict())
    with torch.no_grad():
        assert half(torch.zeros(1, 3, 96, 128)).shape == (1, 21, 48, 64)
    net_input = NetworkInput(size=(128, 96))
    full_top = NetworkSegmenter(model_s1, PASCAL_VOC, name="full", net_input=net_input).predict(rgb)
    half_top = NetworkSegmenter(half, PASCAL_VOC, name="half", net_input=net_input).predict(rgb)
    assert (full_top.labels[..., 0] == half_top.labels[..., 0]).mean() > 0.97
    np.testing.assert_allclose(full_top.probs[..., 0], half_top.probs[..., 0], atol=0.1)


def test_real_frame_finds_kitchen_furniture(model_s1: ESPNetv2Seg) -> None:
    cv2 = pytest.importorskip("cv2")
    frame = FRAMES / "frame-000400.color.jpg"
    if not frame.is_file():
        pytest.skip(f"{frame} is not present")
    rgb = cv2.cvtColor(cv2.imread(str(frame)), cv2.COLOR_BGR2RGB)
    x = cv2.resize(rgb, (512, 384), interpolation=cv2.INTER_LINEAR).astype(np.float32) / 255.0
    x = (x - np.array([0.485, 0.456, 0.406], np.float32)) / np.array([0.229, 0.224, 0.225], np.float32)
    with torch.no_grad():
        labels = model_s1(torch.from_numpy(x).permute(2, 0, 1)[None]).argmax(1)[0].numpy()
    share = np.bincount(labels.ravel(), minlength=21) / labels.size
    # frame 400 looks down on the dining table, chairs around it
    assert share[PASCAL_VOC.id_of("diningtable")] > 0.2
    assert share[[1, 3, 8, 10, 12, 13, 17, 19]].sum() < 0.02  # no aeroplanes, animals or trains in a kitchen


@pytest.mark.slow
def test_onnx_export_holds_the_pooling_weights_as_constants(tmp_path: Path) -> None:
    # filling the adaptive-pooling matrices row by row inside forward traced every row as a scatter: 72k graph
    # nodes for s=2.0 at 432x320 and about 30 s of CPU to open each ONNX Runtime session
    import onnx

    from semmap.perception.network import export_onnx

    torch.manual_seed(0)
    model = ESPNetv2Seg(s=0.5).eval()
    path = export_onnx(model, tmp_path / "e.onnx", (1, 3, 96, 128))
    ops = [n.op_type for n in onnx.load(str(path)).graph.node]
    assert "ScatterND" not in ops and len(ops) < 1500


# --------------------------------------------------------------------------------------------------
# The shipped copy (weights/espnetv2, MIT): a fresh clone segments real frames with nothing from outside
# --------------------------------------------------------------------------------------------------
def test_shipped_espnetv2_files_match_the_manifest_and_carry_their_licence() -> None:
    import hashlib
    import json

    from semmap.perception.registry import ESPNETV2_FILES, MANIFEST, shipped_weights_dir

    folder = shipped_weights_dir()
    external = json.loads((folder / MANIFEST).read_text())["external"]
    assert {Path(e["file"]).name for e in external.values()} == set(ESPNETV2_FILES.values())
    for entry in external.values():
        data = (folder / entry["file"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == entry["sha256"] and len(data) == entry["bytes"]
        assert entry["licence"].startswith("MIT")
    licence = (folder / "espnetv2" / "LICENSE").read_text()
    assert "MIT License" in licence and "Sachin Mehta" in licence


def test_espnetv2_without_weights_segments_with_the_shipped_file() -> None:
    from semmap.perception.registry import make_segmenter

    seg = make_segmenter("espnetv2")
    assert seg.label_set.names == PASCAL_VOC.names


def test_a_changed_shipped_espnetv2_file_is_refused(tmp_path: Path, monkeypatch) -> None:
    import json

    from semmap.errors import ConfigError
    from semmap.perception.registry import ESPNETV2_FILES, MANIFEST, make_segmenter, shipped_espnetv2

    folder = tmp_path / "weights"
    (folder / "espnetv2").mkdir(parents=True)
    target = folder / "espnetv2" / ESPNETV2_FILES["s2"]
    target.write_bytes(shipped_espnetv2().read_bytes())
    (folder / MANIFEST).write_text(json.dumps({"networks": {}, "external": {
        "espnetv2-s2": {"file": f"espnetv2/{target.name}", "sha256": "0" * 64}}}))
    monkeypatch.setenv("SEMMAP_WEIGHTS", str(folder))
    with pytest.raises(ConfigError, match=r"espnetv2_s_2\.0.*sha256 .* differs"):
        make_segmenter("espnetv2")
