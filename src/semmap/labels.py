"""Label sets every layer may use: the simulator's class list (NYUv2-40-like indoor classes with fixed, distinct
display colours), which the simulator renders and the segmenters and instance sources fall back to."""

from __future__ import annotations

import numpy as np

from semmap.types import LabelSet

#: (name, RGB colour) in class-id order; id 0 is "unknown / void". Colours are hand-picked, never white.
_CLASSES: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("unknown", (0, 0, 0)),
    ("wall", (174, 199, 232)),
    ("floor", (152, 223, 138)),
    ("ceiling", (78, 71, 183)),
    ("door", (214, 39, 40)),
    ("window", (197, 176, 213)),
    ("table", (255, 152, 150)),
    ("chair", (188, 189, 34)),
    ("sofa", (140, 86, 75)),
    ("bed", (255, 187, 120)),
    ("cabinet", (31, 119, 180)),
    ("shelf", (148, 103, 189)),
    ("desk", (247, 182, 210)),
    ("monitor", (23, 190, 207)),
    ("keyboard", (82, 84, 163)),
    ("book", (196, 156, 148)),
    ("cup", (227, 119, 194)),
    ("bottle", (44, 160, 44)),
    ("plant", (0, 100, 0)),
    ("lamp", (255, 127, 14)),
    ("picture", (219, 219, 141)),
    ("pillow", (158, 218, 229)),
    ("box", (178, 127, 35)),
    ("person", (220, 20, 60)),
    ("counter", (96, 207, 209)),
    ("curtain", (100, 85, 144)),
    ("refrigerator", (90, 90, 90)),
    ("sink", (112, 128, 144)),
    ("nightstand", (227, 207, 87)),
    ("whiteboard", (240, 240, 200)),
)

INDOOR_LABELS: LabelSet = LabelSet(
    tuple(name for name, _ in _CLASSES),
    np.array([color for _, color in _CLASSES], dtype=np.uint8),
)

#: Classes that are part of the room shell ("stuff"): they get instance id 0 in instance images.
STUFF_CLASSES: frozenset[str] = frozenset({"wall", "floor", "ceiling"})


def class_id(name: str) -> int:
    """Id of ``name`` in :data:`INDOOR_LABELS` (raises ConfigError for unknown names)."""
    return INDOOR_LABELS.id_of(name)


#: NYU Depth v2's 40 classes (Gupta et al. 2013) as ScanNet maps its labels to them (``nyu40id`` 1-40; 0 unknown).
NYU40_NAMES: tuple[str, ...] = (
    "unknown", "wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf", "picture",
    "counter", "blinds", "desk", "shelves", "curtain", "dresser", "pillow", "mirror", "floor mat", "clothes",
    "ceiling", "books", "refridgerator", "television", "paper", "towel", "shower curtain", "box", "whiteboard",
    "person", "night stand", "toilet", "sink", "lamp", "bathtub", "bag", "otherstructure", "otherfurniture",
    "otherprop")


def nyu40_labels() -> LabelSet:
    """NYU-40 with the simulator's colour where a class shares its name, else a distinct colour."""
    from semmap.types import distinct_colors

    colors = distinct_colors(len(NYU40_NAMES))
    for i, name in enumerate(NYU40_NAMES):
        if name in INDOOR_LABELS.names:
            colors[i] = INDOOR_LABELS.colors[INDOOR_LABELS.names.index(name)]
    return LabelSet(NYU40_NAMES, colors)


#: The simulator's classes as NYU-40 ids (``otherprop`` for small things NYU-40 does not name).
_SIM_TO_NYU40 = {"shelf": "shelves", "monitor": "television", "book": "books", "nightstand": "night stand",
                 "refrigerator": "refridgerator", "keyboard": "otherprop", "cup": "otherprop", "bottle": "otherprop",
                 "plant": "otherprop"}


def simulator_to_nyu40() -> np.ndarray:
    """(K,) NYU-40 id of each simulator class id."""
    return np.array([NYU40_NAMES.index(_SIM_TO_NYU40.get(name, name)) for name in INDOOR_LABELS.names], np.uint16)
