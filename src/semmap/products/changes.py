"""What changed between two maps of one place (in one frame): voxels that appeared, disappeared or changed class,
and objects that appeared, disappeared or moved.

A voxel counts as changed only where both maps observed it: occupied in B and seen free in A has appeared,
occupied in A and seen free in B has disappeared; a voxel that one map never saw is unobserved, not a change
(a second recording that skipped a corner must not erase it).

Objects (``objects.json``, their points from ``objects.ply``) are compared by evidence, not by position alone.
Each object's place (the voxels of its points of its class) is looked up in the other map: seen mostly free
(gone; for an object of the later map: new), seen mostly occupied (present: the other recording did not pick it
out as an instance, books in a shelf seen from afar) or seen too little (unseen). Then, per class: objects within
``match_radius`` are the same object (never a gone one with one whose place the other map saw occupied: that is
another object), moved when farther apart than ``move_threshold`` and one end changed; gone and new objects left
over pair as moves however far apart, the most alike in colour first (in size where colour is unknown); parts of
one object the object map kept apart fold into its change; an object left alone disappeared (appeared) only when
gone (new), else its fate is unknown. Clusters of changed voxels that no object covers are objects the object map
missed (``source: voxels``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from semmap.errors import ConfigError
from semmap.keys import coords_to_keys, index_in, pack_keys
from semmap.maps.base import SemanticMap
from semmap.perception.instances.base import thing_classes
from semmap.products.occupancy import FREE, OCCUPIED, OccupancyVolume, map_keys, volume_of_keys

#: Colours of diff.ply: appeared, disappeared, changed class.
CHANGE_COLORS = {"appeared": (40, 200, 60), "disappeared": (220, 40, 40), "relabelled": (50, 90, 230)}


@dataclass(frozen=True)
class VoxelChanges:
    """World centres (N, 3) of the changed voxels per kind, their classes, and the voxels both maps observed."""

    centers: dict[str, np.ndarray]
    labels: dict[str, np.ndarray]
    observed_by_both: int
    unobserved: int

    def counts(self) -> dict[str, int]:
        return {k: len(v) for k, v in self.centers.items()}


def _common_volumes(a: SemanticMap, b: SemanticMap) -> tuple[OccupancyVolume, OccupancyVolume]:
    if abs(float(a.resolution) - float(b.resolution)) > 1e-9:
        raise ConfigError(f"the maps have different resolutions ({a.resolution} m and {b.resolution} m); map both "
                          f"at one resolution to compare them")
    keys = (map_keys(a), map_keys(b))  # read once per map: the union box and both volumes come from them
    both = np.concatenate([k for occ, _, free in keys for k in (occ, free)])
    if len(both) == 0:
        raise ConfigError("both maps are empty: nothing to compare")
    lo, hi = both.min(axis=0), both.max(axis=0)
    return tuple(volume_of_keys(k, float(m.resolution), lo, hi, getattr(m, "label_set", None))
                 for k, m in zip(keys, (a, b), strict=True))  # type: ignore[return-value]


def voxel_changes(a: SemanticMap, b: SemanticMap) -> VoxelChanges:
    """Voxel changes from map ``a`` (before) to map ``b`` (after), both in one frame at one resolution."""
    va, vb = _common_volumes(a, b)
    seen_a, seen_b = va.state >= FREE, vb.state >= FREE
    occ_a, occ_b = va.state == OCCUPIED, vb.state == OCCUPIED
    masks = {"appeared": occ_b & (va.state == FREE), "disappeared": occ_a & (vb.state == FREE),
             "relabelled": occ_a & occ_b & (va.labels != vb.labels)}
    source = {"appeared": vb, "disappeared": va, "relabelled": vb}
    centers, labels = {}, {}
    for kind, mask in masks.items():
        idx = np.argwhere(mask)
        centers[kind] = va.origin + idx * va.resolution
        labels[kind] = source[kind].labels[mask]
    both = seen_a & seen_b
    return VoxelChanges(centers, labels, int(both.sum()), int(((occ_a & ~seen_b) | (occ_b & ~seen_a)).sum()))


#: Where an object's place stands in the other map (:func:`object_status`): ``GONE`` seen mostly free there (for an
#: object of the later map: its place was free before, it is new), ``PRESENT`` seen mostly occupied, ``UNSEEN`` the
#: other map saw too little of it to say.
GONE, PRESENT, UNSEEN = "gone", "present", "unseen"
#: Share and number of an object's voxels the other map must have observed (free or occupied) to say anything
#: about it.
MIN_OBSERVED = 0.3
MIN_OBSERVED_VOXELS = 10
#: Share of the observed ones that must be free for the object to be gone (new).
MIN_FREE = 0.5
#: Margin (m) round an object's box in which its map's occupied voxels of its class are its voxels.
BOX_MARGIN = 0.05
#: A move pairs a gone object with a new one of the same class whose box differs by at most this share per side.
MAX_EXTENT_CHANGE = 0.75


def _box_voxels(record: dict, own: OccupancyVolume) -> np.ndarray:
    """(N, 3) indices of the voxels ``own`` holds occupied by the object's class (any class when the map has no
    class names) inside its upright box grown by ``BOX_MARGIN`` (or near its centroid when it has no box)."""
    box = record.get("box")
    centre = np.asarray(box["center"] if box else record.get("at", record.get("centroid")), np.float64)
    half = (np.asarray(box["extent"], np.float64) / 2 if box else np.zeros(3)) + BOX_MARGIN + own.resolution / 2
    rot = np.asarray(box["rotation"], np.float64) if box else np.eye(3)
    reach = np.abs(rot) @ half  # the world-axis box round the rotated one
    lo = np.maximum(own.index_of((centre - reach)[None])[0], 0)
    hi = np.minimum(own.index_of((centre + reach)[None])[0] + 1, own.shape)
    if np.any(hi <= lo):
        return np.zeros((0, 3), np.int64)
    box_sl = tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))
    occ = own.state[box_sl] == OCCUPIED
    names = list(own.label_set.names) if own.label_set is not None else []
    if record["class"] in names:
        occ &= own.labels[box_sl] == names.index(record["class"])
    idx = np.argwhere(occ) + lo
    local = (own.origin + idx * own.resolution - centre) @ rot  # in the box's axes
    return idx[np.all(np.abs(local) <= half, axis=1)]


#: Fewest voxels of its own class an object's points must fall in for those alone to be its place (else all of them).
MIN_CLASS_VOXELS = 5


def _point_voxels(points: np.ndarray, own: OccupancyVolume, cls: str | None = None) -> np.ndarray:
    """(N, 3) indices of the distinct voxels of the object's points that ``own`` holds occupied: those of its class
    ``cls`` when at least ``MIN_CLASS_VOXELS`` are (an instance mask that spilt onto the table under a cup must not
    make the table the cup's place), else all."""
    idx = np.unique(own.index_of(np.asarray(points, np.float64).reshape(-1, 3)), axis=0)
    idx = idx[np.all((idx >= 0) & (idx < np.array(own.shape)), axis=1)]
    idx = idx[own.state[idx[:, 0], idx[:, 1], idx[:, 2]] == OCCUPIED]
    names = list(own.label_set.names) if own.label_set is not None else []
    if cls in names:
        mine = own.labels[idx[:, 0], idx[:, 1], idx[:, 2]] == names.index(cls)
        if mine.sum() >= MIN_CLASS_VOXELS:
            return idx[mine]
    return idx


def _place(record: dict, own: OccupancyVolume, other: OccupancyVolume, points: np.ndarray | None
           ) -> tuple[str, np.ndarray]:
    """:func:`object_status` and the centre (world, m) of the object's voxels the other map saw free (NaN if none)."""
    has_points = points is not None and len(points) > 0
    idx = _point_voxels(points, own, record["class"]) if has_points else _box_voxels(record, own)
    state = other.state[idx[:, 0], idx[:, 1], idx[:, 2]]
    free, occupied = int((state == FREE).sum()), int((state == OCCUPIED).sum())
    at = own.origin + idx[state == FREE].mean(axis=0) * own.resolution if free else np.full(3, np.nan)
    if len(idx) == 0 or free + occupied < max(MIN_OBSERVED * len(idx), MIN_OBSERVED_VOXELS):
        return UNSEEN, at
    return (GONE if free > MIN_FREE * (free + occupied) else PRESENT), at


def object_status(record: dict, own: OccupancyVolume, other: OccupancyVolume, points: np.ndarray | None = None
                  ) -> str:
    """Whether the other map saw the place of the object (a record of ``objects.json`` in ``own``'s map) free
    (``GONE``), occupied (``PRESENT``) or too little of it (``UNSEEN``); both volumes share one voxel box. Its place
    is the voxels of its ``points`` (``objects.ply``), else of its class in its box."""
    return _place(record, own, other, points)[0]


def _extent(record: dict) -> np.ndarray:
    """Sorted horizontal sides and height of the object's box (m), for telling objects of one class apart."""
    box = record.get("box")
    if not box:
        return np.full(3, np.nan)
    e = np.asarray(box["extent"], np.float64)
    rot = np.asarray(box["rotation"], np.float64)
    vertical = int(np.argmax(np.abs(rot[2])))  # the box axis closest to world z (the map's up is z)
    flat = np.sort(np.delete(e, vertical))
    return np.array([flat[0], flat[1], e[vertical]])


def extent_change(a: dict, b: dict) -> float:
    """Largest relative difference of two objects' box sides (0 alike, 1 nothing alike; 0 without boxes)."""
    ea, eb = _extent(a), _extent(b)
    if np.any(np.isnan(ea)) or np.any(np.isnan(eb)):
        return 0.0
    return float(np.max(np.abs(ea - eb) / np.maximum(np.maximum(ea, eb), 0.1)))


def _assign(cost: np.ndarray) -> list[tuple[int, int]]:
    """Optimal pairs of a cost matrix whose infinite entries are forbidden."""
    if cost.size == 0 or not np.isfinite(cost).any():
        return []
    rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if np.isfinite(cost[r, c])]


#: Two objects are alike in colour when their chromaticities (r, g, b over r + g + b) differ by at most
#: ``MAX_CHROMA_CHANGE`` and their brightnesses by at most a factor ``MAX_BRIGHTNESS_RATIO`` (the same object reads
#: brighter or darker in another spot of the room: measured 0.76-1.24 for simulated moves).
MAX_CHROMA_CHANGE = 0.08
MAX_BRIGHTNESS_RATIO = 1.5
#: Weight of the colour change (1: the limit) against the relative size change in a move's cost.
COLOUR_WEIGHT = 1.0
#: Parts of one object that the object map kept apart: same class, same fate, alike in colour, boxes this close (m).
PART_GAP = 0.1


def colour_change(a: np.ndarray, b: np.ndarray) -> float:
    """How unlike two mean colours (RGB 0..1) are: 1 at the limit of :data:`MAX_CHROMA_CHANGE` or
    :data:`MAX_BRIGHTNESS_RATIO`, whichever is nearer; NaN when either is unknown."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    sa, sb = a.sum(), b.sum()
    if not (np.isfinite(sa) and np.isfinite(sb)) or sa <= 0 or sb <= 0:
        return float("nan")
    chroma = float(np.linalg.norm(a / sa - b / sb)) / MAX_CHROMA_CHANGE
    return max(chroma, abs(float(np.log(sa / sb))) / float(np.log(MAX_BRIGHTNESS_RATIO)))


@dataclass(frozen=True)
class ObjectEvidence:
    """What the maps say of each object of one map: its place in the other map (:func:`object_status`), its mean
    observed colour (RGB 0..1, NaN when unknown), its voxels (sorted packed keys, when known) and the centre of
    those the other map saw free (where it changed; NaN when none)."""

    status: list[str]
    colour: np.ndarray
    voxels: list[np.ndarray] | None = None
    changed_at: np.ndarray | None = None

    def where(self, i: int, record: dict) -> list[float]:
        """Where object ``i`` changed: the centre of its voxels seen free in the other map, else its centroid."""
        at = self.changed_at[i] if self.changed_at is not None else np.full(3, np.nan)
        return [round(float(v), 3) for v in (at if np.all(np.isfinite(at)) else record["centroid"])]


def _no_evidence(n: int) -> ObjectEvidence:
    return ObjectEvidence([GONE] * n, np.full((n, 3), np.nan))


def _shared(ev: ObjectEvidence, i: int, j: int) -> float:
    """Share of the smaller of objects ``i`` and ``j`` (of one map) whose voxels the other also holds."""
    if ev.voxels is None or len(ev.voxels[i]) == 0 or len(ev.voxels[j]) == 0:
        return 0.0
    common = len(np.intersect1d(ev.voxels[i], ev.voxels[j], assume_unique=True))
    return common / min(len(ev.voxels[i]), len(ev.voxels[j]))


def _aabb(record: dict) -> tuple[np.ndarray, np.ndarray]:
    """World-axis box round the object's upright box (a point at its centroid without one)."""
    box = record.get("box")
    if not box:
        c = np.asarray(record["centroid"], np.float64)
        return c, c
    reach = np.abs(np.asarray(box["rotation"], np.float64)) @ (np.asarray(box["extent"], np.float64) / 2)
    return np.asarray(box["center"], np.float64) - reach, np.asarray(box["center"], np.float64) + reach


def _touching(a: dict, b: dict) -> bool:
    (alo, ahi), (blo, bhi) = _aabb(a), _aabb(b)
    return bool(np.all(alo <= bhi + PART_GAP) and np.all(blo <= ahi + PART_GAP))


def _ids(record: dict, key: str) -> dict:
    """The id of an object under ``key`` (``before`` / ``after``), and ``source: voxels`` for one found only in the
    changed voxels (no id)."""
    return {key: None, "source": "voxels"} if record.get("source") == "voxels" else {key: int(record["id"])}


def _pair(cls: str, a: dict, b: dict, at: tuple[list[float], list[float]] | None = None) -> dict:
    """The record of a matched pair: ``from`` / ``to`` at ``at`` (where each end changed), else the centroids."""
    ca, cb = (np.asarray(v, np.float64) for v in (at or (a["centroid"], b["centroid"])))
    return {"class": cls, **_ids(a, "before"), **_ids(b, "after"), "from": [round(float(v), 3) for v in ca],
            "to": [round(float(v), 3) for v in cb], "distance_m": round(float(np.linalg.norm(ca - cb)), 3)}


def _same_objects(ia: list[int], ib: list[int], before: list[dict], after: list[dict],
                  ev: tuple[ObjectEvidence, ObjectEvidence], limits: tuple[float, float]
                  ) -> list[tuple[int, int, bool]]:
    """Pair objects of class ``cls`` that are the same object where they were: nearest centroids within the match
    radius, but never an object whose place went with one whose place the earlier map saw occupied (nor the
    reverse: that is another object the other recording did not pick out), nor one that went with one that came
    unlike it in colour. A pair farther apart than the move
    threshold whose space says one end changed moved (``True``); any other stayed."""
    match_radius, move_threshold = limits
    ca = np.array([before[i]["centroid"] for i in ia], np.float64).reshape(-1, 3)
    cb = np.array([after[j]["centroid"] for j in ib], np.float64).reshape(-1, 3)
    dist = np.linalg.norm(ca[:, None] - cb[None], axis=2)
    sa, sb = np.array([ev[0].status[i] for i in ia], object), np.array([ev[1].status[j] for j in ib], object)
    gone, new = sa == GONE, sb == GONE
    other_object = (gone[:, None] & (sb == PRESENT)[None]) | ((sa == PRESENT)[:, None] & new[None])
    colour = np.array([[colour_change(ev[0].colour[i], ev[1].colour[j]) for j in ib] for i in ia]).reshape(dist.shape)
    other_object |= gone[:, None] & new[None] & (colour > 1.0)  # one went, one came, unlike: two objects
    allowed = (dist <= move_threshold) | ((dist <= match_radius) & ~other_object)
    return [(ia[r], ib[c], bool(dist[r, c] > move_threshold and (gone[r] or new[c])))
            for r, c in _assign(np.where(allowed, dist, np.inf))]


def _moves(ia: list[int], ib: list[int], before: list[dict], after: list[dict],
           ev: tuple[ObjectEvidence, ObjectEvidence]) -> list[tuple[int, int]]:
    """Pair gone objects of class ``cls`` with new ones anywhere (a move is a removal and an addition of one
    object): the most alike in colour and size first, the nearer on a tie; objects unlike in colour (in size where
    a colour is unknown) never pair."""
    if not ia or not ib:
        return []
    size = np.array([[extent_change(before[i], after[j]) for j in ib] for i in ia])
    colour = np.array([[colour_change(ev[0].colour[i], ev[1].colour[j]) for j in ib] for i in ia])
    ca = np.array([before[i]["centroid"] for i in ia], np.float64)
    cb = np.array([after[j]["centroid"] for j in ib], np.float64)
    cost = size + COLOUR_WEIGHT * np.nan_to_num(colour, nan=0.0) + 0.01 * np.linalg.norm(ca[:, None] - cb[None], axis=2)
    alike = np.where(np.isnan(colour), size <= MAX_EXTENT_CHANGE, colour <= 1.0)
    return [(ia[r], ib[c]) for r, c in _assign(np.where(alike, cost, np.inf))]


def _leftovers(records: list[dict], ev: ObjectEvidence, changed: dict[int, dict], used: set[int], kind: str,
               key: str, out: dict) -> None:
    """Report the objects of one map left unpaired: a change where the other map saw their place free (a part of
    a changed object (``changed``: index to its record) of its class and colour, touching it, joins that change's
    ``parts``), else of unknown fate."""
    for i in sorted((i for i in range(len(records)) if i not in used), key=lambda i: -int(records[i].get("points", 0))):
        o = records[i]
        rec = {"class": o["class"], **_ids(o, key), "at": ev.where(i, o)}
        if ev.status[i] != GONE:
            if o.get("source") != "voxels":
                out["unknown"].append({**rec, "at": o["centroid"],
                                       "reason": "occupied" if ev.status[i] == PRESENT else "unobserved"})
            continue
        whole = next((r for j, r in changed.items() if (r["class"] == o["class"] and _touching(records[j], o)
                                                         and not colour_change(ev.colour[i], ev.colour[j]) > 1.0)
                      or _shared(ev, i, j) > 0.5), None)  # a part of it, or the same voxels under another class
        if whole is not None:
            whole.setdefault("parts", [])
            if rec.get(key) is not None:
                whole["parts"].append(rec[key])
            continue
        out[kind].append(rec)
        changed[i] = rec


def object_changes(before: list[dict], after: list[dict], *, match_radius: float = 1.0, move_threshold: float = 0.2,
                   evidence: tuple[ObjectEvidence, ObjectEvidence] | None = None) -> dict[str, list[dict]]:
    """Objects (records of ``objects.json``) that appeared, disappeared, moved or stayed, and those of unknown fate.

    ``evidence`` says per object of each map whether the other map saw its place free and what colour it is
    (:func:`diff_objects`; without it every place counts as seen free). An object of one class within
    ``match_radius`` is the same object; beyond it, an object whose place went and one of its class and colour
    whose place came are one object moved, however far; an unpaired object disappeared (appeared) only where its
    place was seen free, otherwise its fate is unknown (the other map saw its place occupied but picked out no
    object there, or never saw it). Records with ``source: voxels`` are objects found only in the changed voxels."""
    for name, v in (("match radius", match_radius), ("move threshold", move_threshold)):
        if not (np.isfinite(v) and v > 0):
            raise ConfigError(f"the {name} must be a positive distance in metres, got {v}")
    ev = evidence or (_no_evidence(len(before)), _no_evidence(len(after)))
    out: dict[str, list[dict]] = {"appeared": [], "disappeared": [], "moved": [], "stayed": [], "unknown": []}
    moved_a: dict[int, dict] = {}
    moved_b: dict[int, dict] = {}
    used_a: set[int] = set()
    used_b: set[int] = set()
    for cls in sorted({o["class"] for o in before} | {o["class"] for o in after}):
        ia = [i for i, o in enumerate(before) if o["class"] == cls]
        ib = [i for i, o in enumerate(after) if o["class"] == cls]
        same = _same_objects(ia, ib, before, after, ev, (match_radius, move_threshold))
        paired_a, paired_b = {i for i, _, _ in same}, {j for _, j, _ in same}
        far = _moves([i for i in ia if i not in paired_a and ev[0].status[i] == GONE],
                     [j for j in ib if j not in paired_b and ev[1].status[j] == GONE], before, after, ev)
        for i, j, moved in same:
            rec = _pair(cls, before[i], after[j])
            out["moved" if moved else "stayed"].append(rec)
            if moved:
                moved_a[i], moved_b[j] = rec, rec
        for i, j in far:
            rec = _pair(cls, before[i], after[j], (ev[0].where(i, before[i]), ev[1].where(j, after[j])))
            out["moved"].append(rec)
            moved_a[i], moved_b[j] = rec, rec
        paired_a |= {i for i, _ in far}
        paired_b |= {j for _, j in far}
        used_a |= paired_a
        used_b |= paired_b
    _leftovers(before, ev[0], moved_a, used_a, "disappeared", "before", out)
    _leftovers(after, ev[1], moved_b, used_b, "appeared", "after", out)
    return out


def _colour_table(m: SemanticMap) -> tuple[np.ndarray, np.ndarray]:
    """Packed keys (sorted) of the map's occupied voxels and their mean observed colours (0..1)."""
    if hasattr(m, "voxels"):
        v = m.voxels()
        keys, colours = v.keys, v.colors
    else:
        c = m.cloud()
        keys, colours = coords_to_keys(c.centers, c.resolution), c.colors
    packed = pack_keys(keys)
    order = np.argsort(packed)
    return packed[order], np.asarray(colours, np.float64)[order] / 255.0


def _mean_colour(keys: np.ndarray, table: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Mean colour of the map's voxels of the packed ``keys`` (NaN without any)."""
    at = index_in(table[0], keys)
    return table[1][at[at >= 0]].mean(axis=0) if (at >= 0).any() else np.full(3, np.nan)


#: A cluster of appeared (disappeared) voxels of an object class (not wall, floor, ceiling: ``thing_classes``) that
#: no object of its class covers is an object the object map missed when it holds at least this many voxels and
#: spans at least ``MIN_CLUSTER_SIDE`` on two axes (a box's top seen from above counts; a sliver of a surface does
#: not).
MIN_CLUSTER_VOXELS = 30
MIN_CLUSTER_SIDE = 0.2


def _voxel_objects(own: OccupancyVolume, other: OccupancyVolume, records: list[dict]) -> list[tuple[dict, np.ndarray]]:
    """Records (``source: voxels``, no id) and voxel indices of the clusters of voxels ``own`` holds occupied and
    ``other`` saw free that are objects no object record covers (``records``: the objects of both maps)."""
    from scipy import ndimage

    if own.label_set is None:
        return []
    labels, _ = ndimage.label((own.state == OCCUPIED) & (other.state == FREE), structure=np.ones((3, 3, 3)))
    names = list(own.label_set.names)
    things = thing_classes(own.label_set)
    side = int(np.ceil(MIN_CLUSTER_SIDE / own.resolution - 1e-9))
    found = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        idx = np.argwhere(labels[sl] == k) + [s.start for s in sl]
        if len(idx) < MIN_CLUSTER_VOXELS or np.sum(idx.max(axis=0) - idx.min(axis=0) + 1 >= side) < 2:
            continue
        cls_id = int(np.bincount(own.labels[tuple(idx.T)]).argmax())
        if cls_id >= len(names) or not things[cls_id]:
            continue
        cls = names[cls_id]
        lo, hi = own.origin + idx.min(axis=0) * own.resolution, own.origin + idx.max(axis=0) * own.resolution
        centre = own.origin + idx.mean(axis=0) * own.resolution
        if any(r["class"] == cls and np.all((_aabb(r)[0] - PART_GAP <= centre) & (centre <= _aabb(r)[1] + PART_GAP))
               for r in records):
            continue
        box = {"center": ((lo + hi) / 2).tolist(), "rotation": np.eye(3).tolist(),
               "extent": (hi - lo + own.resolution).tolist()}
        found.append(({"id": None, "class": cls, "centroid": centre.tolist(), "box": box, "points": len(idx),
                       "source": "voxels"}, idx))
    return found


def _evidence(recs: list[dict], m: SemanticMap, own: OccupancyVolume, other: OccupancyVolume, pts: dict,
              extra: list[tuple[dict, np.ndarray]]) -> ObjectEvidence:
    """:class:`ObjectEvidence` of the objects ``recs`` of map ``m`` (points by id in ``pts``) and of the objects
    found in its changed voxels (``extra``: gone by construction)."""
    table = _colour_table(m)
    res = float(m.resolution)
    keys = [np.unique(pack_keys(coords_to_keys(pts[int(o["id"])], res))) if int(o["id"]) in pts
            else np.zeros(0, np.int64) for o in recs]
    places = [_place(o, own, other, pts.get(int(o["id"]))) for o in recs]
    keys += [np.unique(pack_keys(coords_to_keys(own.origin + idx * own.resolution, res))) for _, idx in extra]
    return ObjectEvidence([p[0] for p in places] + [GONE] * len(extra),
                          np.array([_mean_colour(k, table) for k in keys]).reshape(-1, 3), keys,
                          np.array([p[1] for p in places] + [r["centroid"] for r, _ in extra]).reshape(-1, 3))


def diff_objects(before: list[dict], after: list[dict], a: SemanticMap, b: SemanticMap, *, match_radius: float = 1.0,
                 move_threshold: float = 0.2, points: tuple[dict, dict] | None = None) -> dict[str, list[dict]]:
    """:func:`object_changes` of the objects of map ``a`` (``before``) and map ``b`` (``after``) and of the objects
    found only in their changed voxels, each object's place looked up in the other map (:func:`object_status`) and
    its colour in its own; ``points`` maps object ids to their points (``objects.ply``) per map."""
    va, vb = _common_volumes(a, b)
    pa, pb = points or ({}, {})
    extra_a, extra_b = _voxel_objects(va, vb, before + after), _voxel_objects(vb, va, before + after)
    ev = (_evidence(before, a, va, vb, pa, extra_a), _evidence(after, b, vb, va, pb, extra_b))
    return object_changes(before + [r for r, _ in extra_a], after + [r for r, _ in extra_b],
                          match_radius=match_radius, move_threshold=move_threshold, evidence=ev)
