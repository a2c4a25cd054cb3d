"""Issue 32, deliverable 4: the segmenter a user already has. A user's ONNX file with a JSON sidecar and a tiny,
randomly initialised ``transformers`` SegFormer (saved offline to a folder) each map a simulated sequence end to end;
class mappings fold a model's classes into the map's; every sidecar mistake is one line naming the file and field.
Nothing here touches a model hub (``HF_HUB_OFFLINE=1``; models are local folders)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from semmap.cli import app
from semmap.config import SemanticsConfig
from semmap.errors import ConfigError, SemmapError
from semmap.labels import INDOOR_LABELS
from semmap.perception.class_map import read_class_map, shipped_class_maps
from semmap.perception.registry import SegmenterName, make_segmenter

torch = pytest.importorskip("torch")

ADE20K = json.loads(shipped_class_maps()["ade20k-150"].read_text())["classes"]
FLOOR_ADE, RUG_ADE = ADE20K.index("floor"), ADE20K.index("rug")


@pytest.fixture(autouse=True)
def _no_hub(monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")  # a hub id is read from the local cache only, never fetched


@pytest.fixture(scope="module")
def sim_seq(tmp_path_factory) -> Path:
    """Three coarse frames of a small simulated office (semmap's 30 classes as ground truth)."""
    from semmap.sim.export import simulate_sequence

    return simulate_sequence(tmp_path_factory.mktemp("user_seg") / "seq", scene_seed=2, kind="office", size="small",
                             frames=3, image_size=(160, 120), fps=2.0)


class _Biased(torch.nn.Module):
    """A stride-2 convolution over an NHWC image whose bias makes class ``favourite`` win nearly everywhere."""

    def __init__(self, classes: int, favourite: int) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.conv = torch.nn.Conv2d(3, classes, 3, stride=2, padding=1)
        with torch.no_grad():
            self.conv.weight.mul_(0.01)
            self.conv.bias.zero_()
            self.conv.bias[favourite] = 8.0

    def forward(self, x):
        return self.conv(x.permute(0, 3, 1, 2))


class _Channels(torch.nn.Module):
    """Logits = the three input channels (NCHW in, NCHW out): shows exactly what the segmenter fed the model."""

    def forward(self, x):
        return x * 1.0


def _export(module, path: Path, example, *, names=("image",), outputs=("logits",), dynamic=None) -> Path:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(module.eval(), (example,), str(path), input_names=list(names), output_names=list(outputs),
                          opset_version=17, dynamo=False, dynamic_axes=dynamic)
    return path


def _sidecar(model: Path, **fields) -> Path:
    path = model.with_suffix(".json")
    path.write_text(json.dumps(fields))
    return path


def _map_labels(out: Path) -> np.ndarray:
    """The most likely class of every occupied voxel of the run's primary map."""
    from semmap.io.native import load_map

    cloud = load_map(out / "map.semmap").cloud()
    return np.asarray(cloud.labels)


# --------------------------------------------------------------------------------------------------
# end to end
# --------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_a_users_onnx_model_maps_a_simulated_sequence(sim_seq, tmp_path):
    model = _export(_Biased(len(ADE20K), RUG_ADE), tmp_path / "ade.onnx", torch.zeros(1, 96, 128, 3),
                    names=("pixels",), dynamic={"pixels": {0: "n"}})
    _sidecar(model, input={"layout": "NHWC", "channels": "BGR", "mean": [0.485, 0.456, 0.406],
                           "std": [0.229, 0.224, 0.225]}, output={"kind": "logits", "layout": "NCHW"},
             labels=ADE20K)
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["run", str(sim_seq), "--out", str(out), "--resolution", "0.2", "--segmenter",
                                 f"onnx:{model}", "--class-map", "ade20k-150", "--batch-size", "2"])
    assert r.exit_code == 0, r.output + repr(r.exception)
    report = json.loads((out / "report.json").read_text())
    assert report["frames_used"] == 3 and report["label_set"] == len(INDOOR_LABELS)
    assert f"onnx:{model}" in report["semantics"] and "ade20k-150" in report["semantics"]
    labels = _map_labels(out)
    assert len(labels) > 50
    assert set(labels.tolist()) == {INDOOR_LABELS.id_of("floor")}, "ADE20K's rug folds into semmap's floor"
    config = json.loads((out / "config.json").read_text())["semantics"]
    assert config["segmenter"] == SegmenterName.ONNX and config["model"] == str(model)


def _tiny_segformer(folder: Path, id2label: dict[int, str], favourite: int, size: int = 64) -> Path:
    """A randomly initialised two-stage SegFormer (a few thousand weights) and its image processor, saved offline."""
    from semmap.perception.hf_models import _transformers

    t = _transformers()
    config = t.SegformerConfig(num_encoder_blocks=2, depths=[1, 1], sr_ratios=[2, 1], hidden_sizes=[8, 16],
                               patch_sizes=[7, 3], strides=[4, 2], num_attention_heads=[1, 1], mlp_ratios=[2, 2],
                               decoder_hidden_size=16, num_labels=len(id2label), id2label=id2label,
                               label2id={v: k for k, v in id2label.items()})
    torch.manual_seed(0)
    model = t.SegformerForSemanticSegmentation(config)
    with torch.no_grad():
        model.decode_head.classifier.bias.zero_()
        model.decode_head.classifier.bias[favourite] = 8.0
    model.save_pretrained(folder)
    t.SegformerImageProcessor(size={"height": size, "width": size}).save_pretrained(folder)
    return folder


@pytest.mark.slow
def test_a_tiny_offline_transformers_model_maps_a_simulated_sequence(sim_seq, tmp_path):
    pytest.importorskip("transformers")
    folder = _tiny_segformer(tmp_path / "segformer", dict(enumerate(ADE20K)), FLOOR_ADE)
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["run", str(sim_seq), "--out", str(out), "--resolution", "0.2", "--segmenter",
                                 f"hf:{folder}"])
    assert r.exit_code == 0, r.output + repr(r.exception)
    report = json.loads((out / "report.json").read_text())
    assert report["frames_used"] == 3
    assert report["label_set"] == 1 + len(ADE20K), "the model's id2label behind semmap's void class 0"
    labels = _map_labels(out)
    assert len(labels) > 50 and set(labels.tolist()) == {1 + FLOOR_ADE}


@pytest.mark.slow
def test_transformers_classes_fold_through_a_class_map(tmp_path):
    pytest.importorskip("transformers")
    folder = _tiny_segformer(tmp_path / "segformer", dict(enumerate(ADE20K)), RUG_ADE)
    seg = make_segmenter(f"hf:{folder}", class_map=Path("ade20k-150"), k=2)
    assert seg.label_set == INDOOR_LABELS
    top = seg.predict(np.random.default_rng(0).integers(0, 255, (60, 80, 3), dtype=np.uint8))
    assert top.labels.shape == (60, 80, 2)
    assert (top.labels[..., 0] == INDOOR_LABELS.id_of("floor")).all()
    np.testing.assert_array_less(top.probs[..., 1], top.probs[..., 0])


def test_mask2former_semantic_scores_agree_with_its_post_processing(tmp_path):
    t = pytest.importorskip("transformers")
    from semmap.perception.hf_models import _transformers

    t = _transformers()
    names = {0: "wall", 1: "floor", 2: "chair"}
    backbone = t.SwinConfig(embed_dim=8, depths=[1, 1, 1, 1], num_heads=[1, 1, 1, 1], window_size=4, image_size=64,
                            out_features=["stage1", "stage2", "stage3", "stage4"])
    config = t.Mask2FormerConfig(backbone_config=backbone, hidden_dim=32, mask_feature_size=32, feature_size=32,
                                 num_queries=4, encoder_layers=1, decoder_layers=2, dim_feedforward=32,
                                 encoder_feedforward_dim=32, num_attention_heads=2, common_stride=4,
                                 id2label=names, label2id={v: k for k, v in names.items()})
    torch.manual_seed(0)
    model = t.Mask2FormerForUniversalSegmentation(config).eval()
    model.save_pretrained(tmp_path / "m2f")
    processor = t.Mask2FormerImageProcessor(size={"height": 64, "width": 64}, do_pad=False)
    processor.save_pretrained(tmp_path / "m2f")
    seg = make_segmenter(f"hf:{tmp_path / 'm2f'}", k=3)
    assert seg.label_set.names == ("unknown", "wall", "floor", "chair")
    rgb = np.random.default_rng(1).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    ours = seg.predict(rgb).labels[..., 0].astype(int) - 1
    with torch.inference_mode():
        x = torch.from_numpy(seg.net_input.batch([rgb]))
        theirs = processor.post_process_semantic_segmentation(model(pixel_values=x), target_sizes=[(64, 64)])[0]
    assert (ours == theirs.numpy()).mean() > 0.99


# --------------------------------------------------------------------------------------------------
# the sidecar: what the model is fed, and every mistake in one line
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("layout", "channels", "first"), [("NCHW", "RGB", 0), ("NHWC", "BGR", 2)])
def test_the_sidecar_says_how_pixels_are_fed(tmp_path, layout, channels, first):
    module = _Channels()
    example = torch.zeros(1, 3, 32, 32) if layout == "NCHW" else torch.zeros(1, 32, 32, 3)
    model = _export(module, tmp_path / "m.onnx", example)
    _sidecar(model, input={"layout": layout, "channels": channels, "scale": 1 / 255, "mean": 0.5, "std": 0.5},
             output={"layout": layout}, labels=["background", "a", "b"])
    seg = make_segmenter(f"onnx:{model}", k=3)
    assert seg.label_set.names == ("background", "a", "b"), "a void first class stays id 0"
    rgb = np.zeros((24, 40, 3), np.uint8)
    rgb[..., 0] = 255  # pure red: normalised (1, -1, -1) in RGB order
    top = seg.predict(rgb)
    assert (top.labels[..., 0] == first).all()
    expected = np.exp(1.0) / (np.exp(1.0) + 2 * np.exp(-1.0))
    np.testing.assert_allclose(top.probs[..., 0], expected, rtol=1e-3)
    _sidecar(model, input={"layout": layout, "channels": channels}, output={"layout": layout, "kind": "probabilities"},
             labels=["background", "a", "b"])  # pixel / 255 read as probabilities: (1, 0, 0), renormalised
    top = make_segmenter(f"onnx:{model}", k=2).predict(rgb // 2)
    assert (top.labels[..., 0] == first).all()
    np.testing.assert_allclose(top.probs[..., 0], 1.0, rtol=1e-5)


def _problem(tmp_path: Path, case: str) -> tuple[Path, Path | None]:
    """A model and sidecar with one mistake each (returns the model and an explicit --segmenter-config)."""
    dynamic = {"image": {2: "h", 3: "w"}} if case == "huge" else None
    model = _export(_Channels(), tmp_path / "m.onnx", torch.zeros(1, 3, 32, 32), dynamic=dynamic)
    good = {"input": {"layout": "NCHW"}, "labels": ["a", "b", "c"]}
    if case == "missing sidecar":
        return model, None
    if case == "missing config file":
        return model, tmp_path / "nowhere.json"
    if case == "rank":
        model = _export(_Channels(), tmp_path / "r.onnx", torch.zeros(3, 32, 32))
        _sidecar(model, **good)
        return model, None
    fields = {"channels": {**good, "labels": ["a", "b"]},
              "unknown field": {**good, "input": {"layout": "NCHW", "stdev": [1, 1, 1]}},
              "layout": {**good, "input": {"layout": "CHW"}},
              "labels": {"input": {"layout": "NCHW"}},
              "size": {**good, "input": {"size": [64, 48]}},
              "std": {**good, "input": {"std": [1, 0, 1]}},
              "huge": {**good, "input": {"size": [90000, 90000]}},
              "json": None}[case]
    if fields is None:
        model.with_suffix(".json").write_text("{\"input\": ")
    else:
        _sidecar(model, **fields)
    return model, None


@pytest.mark.parametrize(("case", "words"), [
    ("missing sidecar", ["m.onnx", "m.json", "sidecar"]),
    ("missing config file", ["nowhere.json", "--segmenter-config"]),
    ("rank", ["r.onnx", "rank 3"]),
    ("channels", ["m.onnx", "3 channels", "m.json", "2 classes"]),
    ("unknown field", ["m.json", "input.stdev"]),
    ("layout", ["m.json", "input.layout", "NCHW or NHWC"]),
    ("labels", ["m.json", "labels"]),
    ("size", ["m.json", "input.size", "64x48", "32x32"]),
    ("std", ["m.json", "input.std", "positive"]),
    ("json", ["m.json", "not valid JSON"]),
    ("huge", ["m.json", "input.size"]),
])
def test_sidecar_mistakes_are_one_line_naming_file_and_field(tmp_path, case, words):
    model, config = _problem(tmp_path, case)
    with pytest.raises(ConfigError) as err:
        make_segmenter(f"onnx:{model}", model_config=config)
    message = str(err.value)
    assert "\n" not in message
    for word in words:
        assert word in message, (word, message)


def test_the_cli_says_what_is_wrong_in_one_line(sim_seq, tmp_path):
    r = CliRunner().invoke(app, ["run", str(sim_seq), "--out", str(tmp_path / "o"), "--segmenter", "onnx"])
    assert isinstance(r.exception, ConfigError) and "onnx:MODEL.onnx" in str(r.exception)
    r = CliRunner().invoke(app, ["run", str(sim_seq), "--out", str(tmp_path / "o"), "--semantics", "oracle",
                                 "--class-map", "ade20k-150"])
    assert isinstance(r.exception, ConfigError) and "--class-map" in str(r.exception)
    assert not (tmp_path / "o").exists()
    (tmp_path / "models").mkdir()
    model = _export(_Channels(), tmp_path / "models" / "m.onnx", torch.zeros(1, 3, 32, 32))
    sidecar = _sidecar(model, labels=["a", "b", "c"])
    for outputs, option in ((["--out", str(model.parent)], "--segmenter"),  # the model's folder
                            (["--out", str(tmp_path / "o"), "--rerun", str(sidecar)], "--segmenter-config")):
        r = CliRunner().invoke(app, ["run", str(sim_seq), *outputs, "--segmenter", f"onnx:{model}"])
        assert isinstance(r.exception, SemmapError), r.output
        assert option in str(r.exception) and "\n" not in str(r.exception)
    assert model.is_file() and sidecar.read_text() == json.dumps({"labels": ["a", "b", "c"]})


def test_an_offline_hub_id_is_refused_in_one_line():
    pytest.importorskip("transformers")
    with pytest.raises(ConfigError) as err:
        make_segmenter("hf:semmap-tests/no-such-model")
    assert "offline" in str(err.value) and "hf:semmap-tests/no-such-model" in str(err.value)
    assert "\n" not in str(err.value)


def test_the_configuration_reads_the_model_after_the_colon():
    s = SemanticsConfig(segmenter="onnx:models/net.onnx")
    assert s.segmenter == SegmenterName.ONNX and s.model == "models/net.onnx"
    s = SemanticsConfig(segmenter="hf:nvidia/segformer-b0-finetuned-ade-512-512")
    assert s.segmenter == SegmenterName.HF and s.model == "nvidia/segformer-b0-finetuned-ade-512-512"
    assert SemanticsConfig.model_validate_json(s.model_dump_json()) == s


# --------------------------------------------------------------------------------------------------
# class mappings
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["ade20k-150", "nyu40", "coco-panoptic-133"])
def test_shipped_class_maps_fit_the_classes_they_were_written_for(name):
    data = json.loads(shipped_class_maps()[name].read_text())
    fold = read_class_map(Path(name), data["classes"])
    assert fold.label_set == INDOOR_LABELS
    assert fold.matrix.shape == (len(data["classes"]), len(INDOOR_LABELS))
    np.testing.assert_array_equal(fold.matrix.sum(1), 1.0)
    covered = set(np.flatnonzero(fold.matrix[:, 1:].any(0)) + 1)
    assert {INDOOR_LABELS.id_of(c) for c in ("wall", "floor", "chair", "table", "monitor")} <= covered


def test_a_class_map_adds_the_probabilities_of_classes_it_folds_together(tmp_path):
    path = tmp_path / "map.json"
    path.write_text(json.dumps({"labels": ["void", "ground", "thing"],
                                "map": {"floor": "ground", "Rug ": "ground", "2": "thing", "sky": None}}))
    fold = read_class_map(path, ["floor", "rug", "lamp, light", "sky", "tree"])
    probs = np.array([[[0.3, 0.3, 0.2, 0.1, 0.1]]], np.float32)
    np.testing.assert_allclose(fold.apply(probs)[0, 0], [0.2, 0.6, 0.2])
    path.write_text(json.dumps({"map": {"lamp": "lamp", "tree": "plant"}}))
    assert read_class_map(path, ["floor", "lamp, light", "tree"]).label_set == INDOOR_LABELS
    path.write_text(json.dumps({"map": {"sofa": "sofa"}}))
    with pytest.raises(ConfigError, match=r"map\.json: map key 'sofa' is not one of the model's 2 classes"):
        read_class_map(path, ["floor", "rug"])
    path.write_text(json.dumps({"map": {"rug": "carpet"}}))
    with pytest.raises(ConfigError, match=r"map\.json: map\['rug'\] = 'carpet' is not a label"):
        read_class_map(path, ["floor", "rug"])


@pytest.mark.slow
def test_an_exported_network_runs_as_semmap_runs_it_itself(tmp_path):
    """ESPNetv2 (random weights, small) through ``onnx:`` and a sidecar gives the probabilities semmap's own network
    runner gives: the same resize, normalisation and sampling of a half-resolution, corner-aligned output."""
    from semmap.perception.espnetv2 import ESPNetv2Seg
    from semmap.perception.network import NetworkInput, NetworkSegmenter
    from semmap.perception.voc import PASCAL_VOC, VOC_NAMES

    torch.manual_seed(0)
    net = ESPNetv2Seg(0.5, len(VOC_NAMES), full_resolution=False).eval()
    model = _export(net, tmp_path / "esp.onnx", torch.zeros(1, 3, 48, 64))
    _sidecar(model, input={"size": [64, 48], "mean": [0.485, 0.456, 0.406], "std": [0.229, 0.224, 0.225]},
             output={"align_corners": True}, labels=list(VOC_NAMES))
    ours = NetworkSegmenter(net, PASCAL_VOC, name="espnetv2", net_input=NetworkInput(size=(64, 48), short_side=None),
                            k=3)
    user = make_segmenter(f"onnx:{model}", k=3)
    assert user.label_set.names == PASCAL_VOC.names
    rgb = np.random.default_rng(2).integers(0, 255, (90, 120, 3), dtype=np.uint8)
    a, b = ours.predict(rgb), user.predict(rgb)
    assert (a.labels == b.labels).mean() > 0.999
    np.testing.assert_allclose(a.probs, b.probs, atol=1e-4)
