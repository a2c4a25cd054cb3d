"""The structure segmenter (issue 45): wall, floor and ceiling from depth and gravity, on simulated views against
their ground truth, its up-direction sources, NAME+structure, and the real-recording default."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from semmap.labels import INDOOR_LABELS
from semmap.perception.structure.compose import WithStructure, fold_to
from semmap.perception.structure.gravity import UpSource, parse_up
from semmap.perception.structure.segmenter import StructureSegmenter, structure_topk
from semmap.perception.voc import PASCAL_VOC
from semmap.sim.noise import KinectNoise
from semmap.sim.render import Renderer
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import heading_pose
from semmap.types import EMPTY_LABEL, Frame, TopKProbs

WALL, FLOOR, CEILING = (INDOOR_LABELS.id_of(n) for n in ("wall", "floor", "ceiling"))
#: Things that lie flat on a wall: depth sees only the wall there, so these pixels are left out of structure's
#: own scores (the network names them in NAME+structure; test_composition_keeps_a_picture_on_the_wall).
ON_WALL = [INDOOR_LABELS.id_of(n) for n in ("picture", "whiteboard", "window", "door", "curtain")]
WORLD_UP = np.array([0.0, 0.0, 1.0])  # the simulator's world frame is z-up


@pytest.fixture(scope="module")
def bedroom() -> Renderer:
    scene = generate_scene(4, "bedroom")
    return Renderer(scene, noise=KinectNoise(seed=1))


def _view(renderer: Renderer, yaw: float, pitch: float, roll: float = 0.0, height: float = 1.5,
          posed: bool = False) -> Frame:
    room = renderer.scene.rooms[0]
    c = (room.bounds_min + room.bounds_max) / 2
    T = heading_pose((c[0], c[1], height), np.radians(yaw), np.radians(pitch), np.radians(roll))
    v = renderer.render(T)
    return Frame(0, 0.0, v.rgb, v.depth, renderer.intrinsics, T if posed else None, v.labels.astype(np.uint16))


def _predicted(probs: np.ndarray) -> np.ndarray:
    full = np.concatenate([probs, 1.0 - probs.sum(-1, keepdims=True)], -1)
    return np.array([WALL, FLOOR, CEILING, 0])[full.argmax(-1)]


def _ious(frames: list[Frame], seg: StructureSegmenter) -> dict[int, float]:
    inter, union = dict.fromkeys((WALL, FLOOR, CEILING), 0), dict.fromkeys((WALL, FLOOR, CEILING), 0)
    for f in frames:
        pred = _predicted(seg.probabilities(f))
        scored = (f.labels > 0) & ~np.isin(f.labels, ON_WALL)
        for c in inter:
            inter[c] += int(np.sum((pred == c) & (f.labels == c) & scored))
            union[c] += int(np.sum(((pred == c) | (f.labels == c)) & scored))
    return {c: inter[c] / union[c] for c in inter if union[c]}


def _true_up(frame: Frame, T: np.ndarray) -> np.ndarray:
    return T[:3, :3].T @ WORLD_UP


@pytest.mark.slow
def test_single_frames_of_a_clean_room_get_wall_floor_and_ceiling_right(bedroom) -> None:
    """No pose, up estimated from each frame alone: IoU >= 0.9 for all three over views that see them."""
    views = [_view(bedroom, yaw, pitch) for yaw in (0, 200) for pitch in (-25, 20, 0)]
    ious = _ious(views, StructureSegmenter())
    assert set(ious) == {WALL, FLOOR, CEILING}
    assert all(v >= 0.9 for v in ious.values()), ious


@pytest.mark.slow
def test_a_tilted_camera_finds_up_and_the_floor(bedroom) -> None:
    frame = _view(bedroom, 300, -20, roll=20, posed=True)
    view = StructureSegmenter().analyse(frame.with_(T_world_cam=None))
    err = np.degrees(np.arccos(np.clip(view.up.up @ _true_up(frame, frame.T_world_cam), -1, 1)))
    assert view.up.source == UpSource.DEPTH and err < 5.0
    pred = _predicted(view.probs)
    truth = frame.labels == FLOOR
    assert np.sum(pred[truth] == FLOOR) / truth.sum() > 0.9


def test_with_no_floor_in_view_nothing_is_called_floor(bedroom) -> None:
    frame = _view(bedroom, 90, 25)
    assert not np.any(frame.labels == FLOOR)
    pred = _predicted(StructureSegmenter().probabilities(frame))
    assert np.mean(pred == FLOOR) < 0.002
    assert np.mean(pred[frame.labels == CEILING] == CEILING) > 0.9


def test_probabilities_say_how_sure_and_leave_the_rest_unknown(bedroom) -> None:
    frame = _view(bedroom, 0, -25)
    seg = StructureSegmenter()
    probs = seg.probabilities(frame)
    assert probs.dtype == np.float32 and probs.min() >= 0 and probs.sum(-1).max() <= 0.95 + 1e-5
    sets = structure_topk(probs, seg.ids, 3)
    furniture = ~np.isin(frame.labels, [0, WALL, FLOOR, CEILING, *ON_WALL])
    assert np.mean(sets.labels[..., 0][furniture] == 0) > 0.8  # furniture: unknown, not a guess
    assert np.allclose(sets.probs.sum(-1), 1.0, atol=1e-5)  # the unknown mass is one of the entries
    no_depth = frame.depth == 0
    if no_depth.any():
        assert np.all(sets.labels[..., 0][no_depth] == 0)


# ------------------------------------------------------------------ where up comes from
def test_up_sources_first_found_wins(bedroom) -> None:
    frame = _view(bedroom, 0, -25, posed=True)
    T = frame.T_world_cam
    truth = _true_up(frame, T)
    # the recording's accelerometer wins over everything, even when it says something odd
    tilted = truth + np.array([0.2, 0.0, 0.0])
    view = StructureSegmenter(up_world=WORLD_UP).analyse(frame.with_(up_cam=tilted / np.linalg.norm(tilted)))
    assert view.up.source == UpSource.DATASET and np.allclose(view.up.up, tilted / np.linalg.norm(tilted))
    # a declared gravity-aligned world frame, carried into the frame by its pose
    view = StructureSegmenter(up_world=WORLD_UP).analyse(frame)
    assert view.up.source == UpSource.DECLARED and np.allclose(view.up.up, truth)
    # nothing given: from the depth alone
    view = StructureSegmenter().analyse(frame.with_(T_world_cam=None))
    assert view.up.source == UpSource.DEPTH and np.degrees(np.arccos(view.up.up @ truth)) < 3.0


def test_a_sequence_carries_up_and_the_floor_into_a_frame_that_shows_neither_well(bedroom) -> None:
    """After two good views, a view at the floor alone (ambiguous from one frame: floor or wall?) is right."""
    seg = StructureSegmenter()
    for yaw in (0, 200):
        seg.analyse(_view(bedroom, yaw, -25, posed=True))
    down = _view(bedroom, 300, -75, posed=True)
    view = seg.analyse(down)
    assert view.up.source == UpSource.MAP
    assert np.degrees(np.arccos(view.up.up @ _true_up(down, down.T_world_cam))) < 3.0
    pred = _predicted(view.probs)
    assert np.mean(pred[down.labels == FLOOR] == FLOOR) > 0.9


def test_up_axis_option_parses_axes_and_vectors() -> None:
    assert np.allclose(parse_up("+z"), [0, 0, 1]) and np.allclose(parse_up("-y"), [0, -1, 0])
    assert np.allclose(parse_up("0,0,2"), [0, 0, 1])
    from semmap.errors import ConfigError

    for bad in ("up", "0,0,0", "1,2"):
        with pytest.raises(ConfigError, match="--up"):
            parse_up(bad)


def test_tum_accelerometer_gives_each_frame_its_up_direction(tmp_path) -> None:
    from helpers import make_frames
    from semmap.datasets import open_dataset
    from semmap.io.tum_writer import write_tum_sequence

    frames = make_frames(4, with_labels=False)
    write_tum_sequence(tmp_path / "seq", frames)
    lines = ["# timestamp ax ay az"]
    for f in frames:  # at rest the Kinect reads the specific force: +9.81 m/s² along up, here camera -y tipped
        for dt in (-0.02, 0.0, 0.02):
            lines.append(f"{f.timestamp + dt:.6f} 0.0 -9.5 -2.4")
    lines.append(f"{frames[0].timestamp + 0.01:.6f} 30.0 0.0 0.0")  # a jolt of the hand: not gravity, left out
    (tmp_path / "seq" / "accelerometer.txt").write_text("\n".join(lines) + "\n")
    got = list(open_dataset(tmp_path / "seq", "auto"))
    expected = np.array([0.0, -9.5, -2.4]) / np.linalg.norm([0.0, -9.5, -2.4])
    assert all(np.allclose(f.up_cam, expected) for f in got)
    (tmp_path / "seq" / "accelerometer.txt").write_text("1.0 0.1 x 9.8\n")
    from semmap.errors import DatasetError

    with pytest.raises(DatasetError, match=r"accelerometer\.txt:1"):
        list(open_dataset(tmp_path / "seq", "auto"))


# ------------------------------------------------------------------ NAME+structure
class _FixedNetwork:
    """A network that calls every pixel a chair (0.6), with a picture (0.9) on one block of the image."""

    name = "fixed"

    def __init__(self, picture: tuple[slice, slice]):
        self.picture = picture

    @property
    def label_set(self):
        return INDOOR_LABELS

    def segment(self, frame: Frame) -> TopKProbs:
        h, w = frame.depth.shape
        labels = np.full((h, w, 3), EMPTY_LABEL, np.uint16)
        probs = np.zeros((h, w, 3), np.float32)
        labels[..., 0], probs[..., 0] = INDOOR_LABELS.id_of("chair"), 0.6
        labels[..., 1], probs[..., 1] = WALL, 0.1
        labels[(*self.picture, 0)] = INDOOR_LABELS.id_of("picture")
        probs[(*self.picture, 0)] = 0.9
        return TopKProbs(labels, probs)


@pytest.mark.slow
def test_structure_owns_the_shell_where_sure_and_the_network_the_rest(bedroom) -> None:
    frame = _view(bedroom, 0, -25)
    block = (slice(100, 160), slice(300, 400))
    combined = WithStructure(_FixedNetwork(block), StructureSegmenter(), k=3)
    assert combined.name == "fixed+structure" and combined.label_set is INDOOR_LABELS
    sets = combined.segment(frame)
    top = sets.labels[..., 0]
    probs = StructureSegmenter().probabilities(frame)
    structure = _predicted(probs)
    sure = np.isin(structure, [WALL, FLOOR, CEILING])
    unsure = probs.sum(-1) < 0.2  # (in between, the mixture decides: wall 0.4 + 0.6 x 0.1 beats chair 0.6 x 0.6)
    outside = np.ones(top.shape, bool)
    outside[block] = False
    assert np.mean(top[sure & outside] == structure[sure & outside]) > 0.99
    assert np.all(top[unsure & outside] == INDOOR_LABELS.id_of("chair"))
    assert np.all(top[block] == INDOOR_LABELS.id_of("picture"))  # flat on the wall: the network's call stands
    assert np.all(sets.probs.sum(-1) <= 1.0 + 1e-5) and np.all(np.diff(sets.probs, axis=-1) <= 1e-7)


def test_voc_classes_fold_into_semmap_names() -> None:
    ids, dropped = fold_to(PASCAL_VOC)
    name = dict(zip(PASCAL_VOC.names, (INDOOR_LABELS.names[i] for i in ids), strict=True))
    assert name["diningtable"] == "table" and name["tvmonitor"] == "monitor" and name["chair"] == "chair"
    assert name["background"] == "unknown" and name["aeroplane"] == "unknown" and "cow" in dropped


def test_segmenter_names_with_structure(bedroom) -> None:
    from semmap.config import SemanticsConfig
    from semmap.perception.registry import make_segmenter

    c = SemanticsConfig(segmenter="onnx:model.onnx+structure")
    assert (c.segmenter.value, c.model, c.add_structure) == ("onnx", "model.onnx", True)
    c = SemanticsConfig(segmenter="espnetv2+structure", up="+z")
    assert c.segmenter.value == "espnetv2" and c.add_structure
    with pytest.raises(ValueError, match="name a network"):
        SemanticsConfig(segmenter="structure+structure")
    seg = make_segmenter("structure")
    assert isinstance(seg, StructureSegmenter) and seg.label_set is INDOOR_LABELS
    seg = make_segmenter("oracle+structure", label_set=INDOOR_LABELS)
    assert seg.name == "oracle+structure" and isinstance(seg, WithStructure)


# ------------------------------------------------------------------ the real default
def _real_sequence(tmp_path, *, labels: bool = False):
    from helpers import make_room_frames
    from semmap.io.tum_writer import write_tum_sequence

    frames = make_room_frames(3)
    if not labels:
        frames = [f.with_(labels=None) for f in frames]
    write_tum_sequence(tmp_path / "rec", frames)
    return tmp_path / "rec"


def test_a_real_unlabelled_recording_gets_espnetv2_plus_structure(tmp_path, caplog) -> None:
    from semmap.config import InputConfig, OutputConfig, RunConfig
    from semmap.run.real_default import REAL_DEFAULT, with_real_default

    config = RunConfig(input=InputConfig(dataset=_real_sequence(tmp_path)), output=OutputConfig(out=tmp_path / "o"))
    with caplog.at_level(logging.INFO, logger="semmap"):
        resolved = with_real_default(config)
    assert resolved.semantics.segmenter.value == "espnetv2" and resolved.semantics.add_structure
    assert [r.getMessage() for r in caplog.records].count(next(
        r.getMessage() for r in caplog.records if REAL_DEFAULT in r.getMessage())) == 1
    # --semantics none, or a labelled recording, keep what they ask for
    from semmap.config import SemanticsConfig, SemanticSource

    none = config.model_copy(update={"semantics": SemanticsConfig(source=SemanticSource.NONE)})
    assert with_real_default(none).semantics.segmenter is None
    labelled = config.model_copy(update={"input": InputConfig(dataset=_real_sequence(tmp_path / "l", labels=True))})
    assert with_real_default(labelled).semantics.segmenter is None


def test_a_simulator_network_on_a_real_recording_warns_once_naming_the_default(tmp_path, caplog) -> None:
    from semmap.config import InputConfig, OutputConfig, RunConfig, SemanticsConfig
    from semmap.run.real_default import REAL_DEFAULT, with_real_default

    config = RunConfig(input=InputConfig(dataset=_real_sequence(tmp_path)), output=OutputConfig(out=tmp_path / "o"),
                       semantics=SemanticsConfig(segmenter="fcn"))
    with caplog.at_level(logging.WARNING, logger="semmap"):
        assert with_real_default(config) is config
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "fcn" in warned[0] and REAL_DEFAULT in warned[0]


# ------------------------------------------------------------------ the room yardstick (real frames, no hand labels)
@pytest.mark.slow
def test_the_room_yardstick_finds_a_simulated_rooms_shell_and_labels_its_frames() -> None:
    """Fitted on a posed walk through a clean simulated room, the yardstick's labels agree with the simulator's
    own wall and floor labels (wall-mounted things left out: they lie on the wall plane)."""
    from semmap.datasets.simulated import SimulatedDataset
    from semmap.eval.room_yardstick import FLOOR_ID, WALL_ID, fit_room, label_frame

    walk = SimulatedDataset.default(scene_seed=3, kind="bedroom", frames=96)
    frames = list(SimulatedDataset(walk.scene, walk.poses[::8], seed=3))
    room = fit_room(frames)
    assert np.degrees(np.arccos(abs(room.up @ WORLD_UP))) < 1.0
    assert room.floor is not None and abs(room.floor.offset) < 0.03  # the simulator's floor is z = 0
    assert len(room.walls) >= 2
    agree = {WALL: [0, 0], FLOOR: [0, 0]}
    for f in frames:
        lab = label_frame(f, room)
        scored = (f.depth > 0) & ~np.isin(f.labels, ON_WALL) & (f.labels > 0)
        for ours, theirs in ((WALL_ID, WALL), (FLOOR_ID, FLOOR)):
            a, b = (lab == ours) & scored, (f.labels == theirs) & scored
            agree[theirs][0] += int(np.sum(a & b))
            agree[theirs][1] += int(np.sum(a | b))
    assert agree[FLOOR][0] / agree[FLOOR][1] > 0.9 and agree[WALL][0] / agree[WALL][1] > 0.85, agree


def test_structure_confusion_counts_against_the_yardstick() -> None:
    from semmap.eval.room_yardstick import iou_of, structure_confusion

    yard = np.array([[0, 1, 1, 2], [2, 4, 4, 3]], np.uint8)
    pred = np.array([[1, 1, 4, 2], [2, 1, 4, 4]], np.uint8)
    conf = structure_confusion(pred, yard)
    assert conf.tolist() == [[1, 1, 1], [2, 0, 0], [0, 0, 1]]  # the no-depth pixel (0) is not scored
    assert iou_of(conf) == {"wall": 1 / 3, "floor": 1.0, "ceiling": 0.0}

