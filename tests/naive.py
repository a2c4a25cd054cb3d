"""Slow, obviously-correct reference versions of the kernels, for comparison on small inputs."""

from __future__ import annotations

import numpy as np

EMPTY = 65535


def fuse_reference(map_set: dict[int, float], meas_set: dict[int, float], lam: float,
                   k: int = 3, max_confidence: float = 1.0) -> dict[int, float]:
    """Algorithm 1 + Bayes + top-k, written with dicts straight from the paper's pseudocode."""
    return fuse_reference_posterior(map_set, meas_set, lam, k, max_confidence)[0]


def fuse_reference_posterior(map_set: dict[int, float], meas_set: dict[int, float], lam: float,
                             k: int = 3, max_confidence: float = 1.0) -> tuple[dict[int, float], list[float]]:
    """(top-k set, every posterior value sorted descending) of :func:`fuse_reference`."""
    if not meas_set:
        return dict(map_set), sorted(map_set.values(), reverse=True)
    if not map_set:
        return dict(meas_set), sorted(meas_set.values(), reverse=True)
    g, c = dict(map_set), dict(meas_set)
    o1 = max(1.0 - sum(g.values()), 0.0)
    o2 = max(1.0 - sum(c.values()), 0.0)
    if set(g) != set(c):
        for lab in sorted((l for l in g if l not in c), key=lambda l: (-map_set[l], l)):
            c[lab] = lam * o2
            o2 *= 1.0 - lam
        for lab in sorted((l for l in meas_set if l not in map_set), key=lambda l: (-meas_set[l], l)):
            g[lab] = lam * o1
            o1 *= 1.0 - lam
    post = {lab: g[lab] * c[lab] for lab in g}
    total = sum(post.values()) + o1 * o2
    post = {lab: p / total for lab, p in post.items()}
    top = sorted(post.items(), key=lambda kv: (-kv[1], kv[0]))[:k]
    out = {lab: p for lab, p in top if np.float32(p) > 0}
    if out:
        best = max(out, key=out.get)
        out[best] = min(out[best], max_confidence)
    return out, sorted(post.values(), reverse=True)


def as_arrays(s: dict[int, float], k: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A {label: prob} set as sorted (labels uint16, probs float32) arrays of length k."""
    items = sorted(s.items(), key=lambda kv: (-kv[1], kv[0]))[:k]
    labels = np.full(k, EMPTY, np.uint16)
    probs = np.zeros(k, np.float32)
    for i, (lab, p) in enumerate(items):
        labels[i], probs[i] = lab, p
    return labels, probs


def as_dict(labels: np.ndarray, probs: np.ndarray) -> dict[int, float]:
    return {int(l): float(p) for l, p in zip(labels, probs, strict=True) if l != EMPTY}


def octomap_states(tree, resolution: float) -> dict[tuple[int, int, int], bool]:
    """{finest key: occupied} of a pyoctomap tree, expanding pruned leaves (slow, small trees only)."""
    out = {}
    for leaf in tree.begin_leafs():
        size = leaf.getSize()
        n = max(1, round(size / resolution))
        c = np.asarray(leaf.getCoordinate(), np.float64)
        lo = np.floor((c - size / 2) / resolution + 0.5).astype(np.int64) + 32768
        occ = tree.isNodeOccupied(leaf)
        for dx in range(n):
            for dy in range(n):
                for dz in range(n):
                    out[(int(lo[0] + dx), int(lo[1] + dy), int(lo[2] + dz))] = occ
    return out


def likelihood_scores(R, t, pts, labels, probs, others, prior, tables, use_semantics, eps, log_rand):
    """Per-particle sum of tabulated log-likelihoods, one particle and point at a time (localization kernel)."""
    n_cls = prior.num_classes
    out = np.zeros(len(R))
    for i in range(len(R)):
        for j in range(len(pts)):
            x = R[i] @ pts[j].astype(np.float64) + t[i]
            ijk = np.floor((x - prior.origin) / prior.resolution).astype(int)
            if (ijk < 0).any() or (ijk >= np.asarray(prior.shape)).any():
                out[i] += log_rand
                continue
            v = prior.nearest[(ijk[0] * prior.shape[1] + ijk[1]) * prior.shape[2] + ijk[2]]
            if v < 0:
                out[i] += log_rand
                continue
            cell = np.floor((prior.centers[v].astype(np.float64) - prior.origin) / prior.resolution)
            d2 = float(np.sum((x - (prior.origin + (cell + 0.5) * prior.resolution)) ** 2))
            qd = min(int(d2 * tables.d2_scale + 0.5), len(tables.geo) - 1)
            if qd == len(tables.geo) - 1:
                out[i] += log_rand
                continue
            if not use_semantics or others[j] < 0:
                out[i] += tables.geo[qd]
                continue
            valid = [(int(c), float(p)) for c, p in zip(labels[j], probs[j], strict=True) if 0 < c < n_cls]
            q = {c: float(prior.class_q[v, c]) for c, _ in valid}
            rest = n_cls - 1 - len(valid)
            share = others[j] / rest if rest > 0 else 0.0
            s = (sum(p * q[c] for c, p in valid) + share * max(255.0 - sum(q.values()), 0.0)) / 255.0
            f = (1 - eps) * (n_cls - 1) * s + eps
            x = tables.gauss[qd] * f
            out[i] += tables.log_mix[min(int(x * tables.x_scale + 0.5), len(tables.log_mix) - 1)]
    return out


def cosine_scores(R, t, pts, local_labels, prior):
    """The paper's cosine weight per particle, one particle at a time (localization kernel)."""
    out = np.zeros(len(R))
    a = local_labels.astype(np.float64)
    for i in range(len(R)):
        x = pts.astype(np.float64) @ R[i].T + t[i]
        ijk = np.floor((x - prior.origin) / prior.resolution).astype(int)
        inside = ((ijk >= 0) & (ijk < np.asarray(prior.shape))).all(axis=1)
        b = np.zeros(len(pts))
        flat = (ijk[inside, 0] * prior.shape[1] + ijk[inside, 1]) * prior.shape[2] + ijk[inside, 2]
        b[inside] = prior.top_label[flat]
        nb = np.linalg.norm(b)
        out[i] = a @ b / (np.linalg.norm(a) * nb) if nb > 0 and np.linalg.norm(a) > 0 else 0.0
    return out


def cell_mean_reference(keys: np.ndarray, valid: np.ndarray, packed: np.ndarray, labels: np.ndarray,
                        probs: np.ndarray, num_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """The OctoMap's mean evidence per cell ``packed`` (m,): each cell's points gathered in input order, a float64
    sum per class (starting at 0.0) divided by the points, the k largest (ties: the lower class); one point: its
    set as given."""
    m, k = packed.shape[0], labels.shape[1]
    cell_of = {int(p): j for j, p in enumerate(packed)}
    members: dict[int, list[int]] = {}
    for i in np.flatnonzero(valid):
        x, y, z = (int(v) for v in keys[i])
        j = cell_of.get(x | y << 16 | z << 32)
        if j is not None:
            members.setdefault(j, []).append(int(i))
    out_labels = np.full((m, k), EMPTY, np.uint16)
    out_probs = np.zeros((m, k), np.float32)
    for j, points in members.items():
        if len(points) == 1:
            out_labels[j], out_probs[j] = labels[points[0]], probs[points[0]]
            continue
        sums: dict[int, float] = {}
        for i in points:
            for lab, p in zip(labels[i].tolist(), probs[i].tolist(), strict=True):
                if lab != EMPTY and lab < num_classes:
                    sums[lab] = sums.get(lab, 0.0) + p
        for c, (lab, v) in enumerate(sorted(sums.items(), key=lambda kv: (-kv[1], kv[0]))[:k]):
            out_labels[j, c], out_probs[j, c] = lab, np.float32(v / len(points))
    return out_labels, out_probs
