"""What changed between two maps of one place (in one frame): voxels that appeared, disappeared or changed class,
and objects that appeared, disappeared or moved.

A voxel counts as changed only where both maps observed it: occupied in B and seen free in A has appeared,
occupied in A and seen free in B has disappeared; a voxel that one map never saw is unobserved, not a change
(a second recording that skipped a corner must not erase it). Objects are matched by class, nearest centroids
first (an optimal assignment within ``match_radius``); a matched pair farther apart than ``move_threshold`` moved.
An unmatched object counts as appeared or disappeared only where the other map saw most of its voxels free
(:func:`confirmed_by_space`): an object one recording did not pick out as an instance, but whose space the other
map still saw occupied (books in a shelf seen from afar) or never saw, is not a change.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from semmap.errors import ConfigError
from semmap.maps.base import SemanticMap
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


def object_changes(before: list[dict], after: list[dict], *, match_radius: float = 1.0,
                   move_threshold: float = 0.2) -> dict[str, list[dict]]:
    """Objects (records of ``objects.json``) that appeared, disappeared, moved or stayed."""
    for name, v in (("match radius", match_radius), ("move threshold", move_threshold)):
        if not (np.isfinite(v) and v > 0):
            raise ConfigError(f"the {name} must be a positive distance in metres, got {v}")
    out: dict[str, list[dict]] = {"appeared": [], "disappeared": [], "moved": [], "stayed": []}
    matched_a, matched_b = set(), set()
    for cls in sorted({o["class"] for o in before} | {o["class"] for o in after}):
        ia = [i for i, o in enumerate(before) if o["class"] == cls]
        ib = [i for i, o in enumerate(after) if o["class"] == cls]
        if not ia or not ib:
            continue
        ca = np.array([before[i]["centroid"] for i in ia], np.float64)
        cb = np.array([after[i]["centroid"] for i in ib], np.float64)
        dist = np.linalg.norm(ca[:, None] - cb[None], axis=2)
        rows, cols = linear_sum_assignment(np.where(dist <= match_radius, dist, 1e6))
        for r, c in zip(rows, cols, strict=True):
            if dist[r, c] > match_radius:
                continue
            matched_a.add(ia[r])
            matched_b.add(ib[c])
            rec = {"class": cls, "before": int(before[ia[r]]["id"]), "after": int(after[ib[c]]["id"]),
                   "from": [round(float(v), 3) for v in ca[r]], "to": [round(float(v), 3) for v in cb[c]],
                   "distance_m": round(float(dist[r, c]), 3)}
            out["moved" if dist[r, c] > move_threshold else "stayed"].append(rec)
    out["disappeared"] = [{"class": o["class"], "before": int(o["id"]), "at": o["centroid"]}
                          for i, o in enumerate(before) if i not in matched_a]
    out["appeared"] = [{"class": o["class"], "after": int(o["id"]), "at": o["centroid"]}
                       for i, o in enumerate(after) if i not in matched_b]
    return out



#: An unmatched object is a change only if the other map saw most of its voxels (those its own map holds occupied
#: within ``EVIDENCE_RADIUS`` of its centroid) free.
EVIDENCE_RADIUS = 0.2


def _freed(record: dict, own: OccupancyVolume, other: OccupancyVolume) -> bool:
    """Whether most of the voxels ``own`` holds occupied by the object's class near its centroid (any class when
    the map has no class names) are seen free in ``other``."""
    r = int(np.ceil(EVIDENCE_RADIUS / own.resolution))
    c = own.index_of(np.asarray(record["at"], np.float64)[None])[0]
    lo, hi = np.maximum(c - r, 0), np.minimum(c + r + 1, own.shape)
    if np.any(hi <= lo):
        return False
    box = tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))
    occ = own.state[box] == OCCUPIED
    names = list(own.label_set.names) if own.label_set is not None else []
    if record["class"] in names:
        occ &= own.labels[box] == names.index(record["class"])
    return bool(occ.any() and (other.state[box][occ] == FREE).mean() > 0.5)


def confirmed_by_space(objects: dict[str, list[dict]], a: SemanticMap, b: SemanticMap) -> dict[str, list[dict]]:
    """``objects`` (of :func:`object_changes` from map ``a`` to map ``b``) less the disappeared objects whose space
    ``b`` did not see free and the appeared ones whose space ``a`` did not see free: an object one recording did
    not pick out as an instance (books in a shelf seen from afar) or never saw is not a change, and a moved object
    whose old place ``b`` did not see free nor its new place ``a`` stayed."""
    va, vb = _common_volumes(a, b)
    moved = [r for r in objects["moved"] if _freed({**r, "at": r["from"]}, va, vb)
             or _freed({**r, "at": r["to"]}, vb, va)]  # else its centroid shifted with what each recording saw
    return {**objects, "disappeared": [r for r in objects["disappeared"] if _freed(r, va, vb)],
            "appeared": [r for r in objects["appeared"] if _freed(r, vb, va)], "moved": moved,
            "stayed": objects["stayed"] + [r for r in objects["moved"] if r not in moved]}
