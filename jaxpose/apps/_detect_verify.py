"""Recognition without correspondences, the second half: from the best poses that the
compiled scoring found to verified detections (see `jaxpose.apps._detect`).

Each candidate pose is refined from matches of its seen model vertices to image
vertices: within a radius, one to one, only where the image vertex's segments leave in
the directions of the model vertex's projected edges, closest first but a three-way
junction holding all its predicted edges before any other (`_match`). Twice, the
linear method (the paper's small-movement Gauss-Newton, `linear_kernel`) over all
candidates in one compiled call; then the acceptance rule of `verify` (chi-square
bounds on the Eq. 8 error and on every residual) at the pose the linear method reaches,
and the support: what the pose predicts (seen vertices and edges) against what the
image holds.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from ..api._programs import stored_jit
from ..geometry._pose import Pose, observations
from ..solvers._components import Mat3, Vec3, mat_to_array, vec_to_array
from ..solvers._kernel_linear import linear_kernel, matches_from_observations
from ..solvers._status import Status
from ._detect_edges import project_vertices, refine_on_edges
from ._polyhedron import Polyhedron, seen_vertices
from ._recognition import verdict

__all__ = ["Detection", "Settings", "refine_and_verify", "vertex_directions"]

VERIFIED = 8  # best refined candidates judged (one compiled call)


@dataclasses.dataclass(frozen=True)
class Detection:
    """One recognised object.

    **Fields:** `model` (name); `R`, `t` (model to world, the camera's world frame);
    `score` (what the image holds of the pose's prediction: each seen vertex near an
    image vertex counts 1, each seen edge the fraction of its length near a detected
    segment; the ranking score); `support` (`score` over what the pose predicts, in
    `[0, 1]`); `vertices` `(k,)` model vertex indices matched to `image_vertices`
    `(k,)` indices into the primitives' vertices, at `pixels` `(k, 2)`; `error` (Eq. 8
    over the matches, px); `status` (the verification's).
    """

    model: str
    R: np.ndarray
    t: np.ndarray
    score: float
    support: float
    vertices: np.ndarray
    image_vertices: np.ndarray
    pixels: np.ndarray
    error: float
    status: Status


def vertex_directions(primitives, points: np.ndarray) -> np.ndarray:
    """`(V, 3, 2)` unit directions of the segments leaving each image vertex (towards
    each segment's far end), zero rows for padding."""
    out = np.zeros((len(points), 3, 2))
    index = np.asarray(primitives.vertices.segments, np.int64).reshape(len(points), -1)
    ends = np.asarray(primitives.segments.ends, np.float64).reshape(-1, 2, 2)
    for v, row in enumerate(index[:, :3]):
        for k, s in enumerate(row):
            if s < 0:
                continue
            far = ends[s, np.argmax(np.linalg.norm(ends[s] - points[v], axis=1))]
            d = far - points[v]
            n = np.hypot(*d)
            if n > 1e-9:
                out[v, k] = d / n
    return out


def _hits(predicted: np.ndarray, found: np.ndarray, cos_tol: float) -> int:
    """How many of the predicted edge directions `predicted` `(k, 2)` an image vertex's
    segment directions `found` `(3, 2)` hold within the tolerance. A match needs at least
    `min(k, 2)` (a junction says which way its edges go; a corner of clutter rarely
    agrees with two predicted edges at once)."""
    if len(predicted) == 0:
        return 0
    return int(np.sum(np.max(predicted @ found.T, axis=1) >= cos_tol))


def _match(K, R, t, model: Polyhedron, points: np.ndarray, directions, radius: float):
    """Model vertices seen at camera-frame pose `(R, t)` matched one to one to image
    vertices within `radius` px whose segments leave in the directions of the vertex's
    projected edges (`_hits`, 20 degrees), the closest pairs first. A junction that
    holds all of three or more predicted edges, nearer this model vertex than any other,
    is the strongest evidence there is (the printed corners about a rounded one hold two
    at most; a pose solved through one of them puts the vertex right on it): such pairs
    come first, and out to `2 * radius` px."""
    seen = seen_vertices(model, R, t, np.zeros(3))
    if len(seen) == 0 or len(points) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    uv_all = project_vertices(K, R, t, model.vertices)
    uv = uv_all[seen]
    seen_set = set(seen.tolist())
    neighbours: dict[int, list[int]] = {int(v): [] for v in seen}
    for a, b in np.asarray(model.edges):
        if int(a) in seen_set and int(b) in seen_set:
            neighbours[int(a)].append(int(b))
            neighbours[int(b)].append(int(a))
    d = np.linalg.norm(uv[:, None] - points[None], axis=-1)
    cos_tol = math.cos(math.radians(20.0))
    closest = d.min(axis=0)
    candidates = []
    pairs_m, pairs_i = np.nonzero(d <= 2 * radius)
    for m in np.unique(pairs_m):
        v = int(seen[m])
        predicted = np.array([uv_all[n] - uv_all[v] for n in neighbours[v]]).reshape(-1, 2)
        length = np.linalg.norm(predicted, axis=1)
        predicted = predicted[length >= 3] / length[length >= 3, None]
        for i in pairs_i[pairs_m == m]:
            hits = _hits(predicted, directions[i], cos_tol)
            full = hits >= max(len(predicted), 3) and d[m, i] <= closest[i]
            if hits < min(len(predicted), 2) or (d[m, i] > radius and not full):
                continue
            candidates.append((not full, float(d[m, i]), int(m), int(i)))
    candidates.sort()
    used_m, used_i, pairs = set(), set(), []
    for _, _, m, i in candidates:
        if m in used_m or i in used_i:
            continue
        used_m.add(m)
        used_i.add(i)
        pairs.append((int(seen[m]), i))
    pairs.sort()
    rows = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return rows[:, 0], rows[:, 1]


def _distinct_count(pixels: np.ndarray, spacing: float) -> int:
    """How many of the matched pixels stand apart: greedily, those at least `spacing`
    px from every one kept before (a cluster of image vertices, as the two borders of
    one drawn line give, counts once)."""
    kept: list[np.ndarray] = []
    for p in pixels:
        if all(np.hypot(*(p - q)) >= spacing for q in kept):
            kept.append(p)
    return len(kept)


def _needed(min_vertices: int, seen: int) -> int:
    """Matched vertices a detection needs: `min_vertices`, or 70% of the seen ones
    where fewer are seen (a small model shows few), and never fewer than 4."""
    return max(4, min(min_vertices, math.ceil(0.7 * seen)))


def _support(K, R, t, model: Polyhedron, matched: int, edist, edge_radius, min_edge):
    """How much of what the pose predicts the image holds: `(held, total, seen)`, `seen`
    the number of seen vertices. Each seen
    vertex counts 1 in `total`, in the image or not, and the `matched` ones (one to one
    with image vertices) 1 in `held`; each seen edge at least `min_edge` px long counts
    1 in `total` and in `held` the fraction of its length (sampled every 2 px) within
    `edge_radius` of a detected segment of about its direction (`edist`, the
    direction-binned maps; outside the image: not held). Shorter edges,
    seen nearly end-on, say nothing either way."""
    bins, H, W = edist.shape
    seen = set(seen_vertices(model, R, t, np.zeros(3)).tolist())
    uv = project_vertices(K, R, t, model.vertices)

    def lookup(p, direction):
        angle = math.atan2(direction[1], direction[0]) % math.pi
        b = min(int(angle * bins / math.pi), bins - 1)
        inside = (p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] < W) & (p[:, 1] < H)
        ij = np.clip(np.floor(p).astype(np.int64), 0, [W - 1, H - 1])
        return np.where(inside, edist[b, ij[:, 1], ij[:, 0]], np.inf)

    total, held = float(len(seen)), float(matched)
    for a, b in np.asarray(model.edges):
        if int(a) not in seen or int(b) not in seen:
            continue
        length = float(np.linalg.norm(uv[b] - uv[a]))
        if length < min_edge:
            continue
        n = max(2, int(length / 2))
        w = (np.arange(n) + 0.5)[:, None] / n
        d = lookup(uv[a] * (1 - w) + uv[b] * w, uv[b] - uv[a])
        total += 1
        held += float(np.mean(d <= edge_radius))
    return held, total, len(seen)


# --------------------------------------------------------------------------- the entry point


def _linear(C, model, image, mask, R, t):
    """Five steps of the linear method (Gauss-Newton on Eq. 8) from every pose `(H, 3, 3)`,
    `(H, 3)` over its matches `(H, V, ...)` (model to world; `C` the world camera):
    `(obs, R, t, error, status)`."""
    obs = jax.vmap(observations, in_axes=(None, 0, 0, 0))(C, model, image, mask)
    m = matches_from_observations(obs)
    R0 = Mat3(*(R[:, i, j] for i in range(3) for j in range(3)))
    t0 = Vec3(*(t[:, i] for i in range(3)))
    R1, t1, error, _, status = linear_kernel(R0, t0, m, iterations=5)
    return obs, mat_to_array(R1), vec_to_array(t1), error, status


@stored_jit
def _linear_or_start(C, model, image, mask, R, t):
    """`_linear`'s poses, the starting ones kept where it did not converge."""
    _, R1, t1, _, status = _linear(C, model, image, mask, R, t)
    good = status == Status.OK
    return jnp.where(good[:, None, None], R1, R), jnp.where(good[:, None], t1, t)


def _padded(rows, models, points, V: int, Hn: int):
    model = np.zeros((Hn, V, 3))
    image = np.zeros((Hn, V, 2))
    mask = np.zeros((Hn, V), bool)
    for r, (name, mv, iv) in enumerate(rows):
        k = len(mv)
        model[r, :k] = np.asarray(models[name].vertices)[mv]
        image[r, :k] = points[iv]
        mask[r, :k] = k >= 4
    return model, image, mask


class Settings(NamedTuple):
    """The options of `detect` that the refinement uses."""

    noise: float
    vertex_radius: float
    edge_radius: float
    min_edge: float
    min_vertices: int
    min_support: float
    max_detections: int
    V: int  # matches per padded row
    rows: int  # rows of the refinement's padded batch


def refine_and_verify(
    C, K, Rc, tc, found, models, points, directions, edist, ends, settings: Settings
):
    """The detections from `found` (`(score, name, R, t)`, camera-frame poses), best
    first (see the module docstring)."""
    noise, vertex_radius, edge_radius, min_edge = settings[:4]
    min_vertices, min_support, max_detections, V, Hn = settings[4:]
    verified = VERIFIED
    # Camera-frame poses to world (x_cam = Rc x_world + tc) and back.
    to_cam = lambda R, t: (Rc @ R, Rc @ t + tc)  # noqa: E731
    Rw = np.stack([Rc.T @ R for _, _, R, _ in found])
    tw = np.stack([Rc.T @ (t - tc) for _, _, _, t in found])
    names = [name for _, name, _, _ in found]
    for radius in (2 * vertex_radius, vertex_radius):
        rows = [
            (n, *_match(K, *to_cam(R, t), models[n], points, directions, radius))
            for n, R, t in zip(names, Rw, tw, strict=True)
        ]
        model, image, mask = _padded(rows, models, points, V, Hn)
        pad = Hn - len(rows)
        with jax.enable_x64(True):
            R1, t1 = _linear_or_start(
                np.asarray(C, np.float64),
                np.asarray(model, np.float64),
                np.asarray(image, np.float64),
                np.asarray(mask),
                np.concatenate([Rw, np.repeat(Rw[:1], pad, 0)]).astype(np.float64),
                np.concatenate([tw, np.repeat(tw[:1], pad, 0)]).astype(np.float64),
            )
        Rw, tw = np.asarray(R1)[: len(rows)], np.asarray(t1)[: len(rows)]
    ranked = []
    for n, R, t in zip(names, Rw, tw, strict=True):
        mv, iv = _match(K, *to_cam(R, t), models[n], points, directions, vertex_radius)
        distinct = _distinct_count(points[iv], 2 * vertex_radius)
        held, total, seen = _support(
            K, *to_cam(R, t), models[n], distinct, edist, edge_radius, min_edge
        )
        if distinct < _needed(min_vertices, seen):
            continue
        if total and held >= min_support * total:
            ranked.append((held, total, n, mv, iv, R, t))
    ranked.sort(key=lambda r: -r[0])
    ranked = ranked[:verified]
    if not ranked:
        return []
    poses = (np.stack([r[5] for r in ranked]), np.stack([r[6] for r in ranked]))
    out = _verify_rows(C, [r[2:5] for r in ranked], models, points, noise, V, verified, poses)
    # Once more on the inliers alone: an outlier (a vertex of a thin face matched to its
    # neighbour's junction) no longer pulls the pose.
    ranked = [
        (*r[:3], r[3][o[3]], r[4][o[3]], o[0], o[1]) if o[4] else r
        for r, o in zip(ranked, out, strict=True)
    ]
    poses = (np.stack([r[5] for r in ranked]), np.stack([r[6] for r in ranked]))
    out = _verify_rows(C, [r[2:5] for r in ranked], models, points, noise, V, verified, poses)
    detections = []
    for (_, _, name, mv, iv, _, _), (Rv, tv, error, inliers, accepted, status) in zip(
        ranked, out, strict=True
    ):
        distinct = _distinct_count(points[iv[inliers]], 2 * vertex_radius)
        if accepted:
            R_cam, t_cam = refine_on_edges(
                K,
                *to_cam(Rv, tv),
                models[name],
                mv[inliers],
                points[iv[inliers]],
                ends,
                min_edge=min_edge,
            )
            Rv, tv = Rc.T @ R_cam, Rc.T @ (t_cam - tc)
        held, total, seen = _support(
            K, *to_cam(Rv, tv), models[name], distinct, edist, edge_radius, min_edge
        )
        if not accepted or distinct < _needed(min_vertices, seen) or held < min_support * total:
            continue
        detections.append(
            Detection(
                name,
                Rv,
                tv,
                held,
                held / total,
                mv[inliers],
                iv[inliers],
                points[iv[inliers]],
                error,
                status,
            )
        )
    detections.sort(key=lambda d: (-d.score, d.error))
    chosen: list[Detection] = []
    outlines: list[np.ndarray] = []
    for d in detections:
        used = set(d.image_vertices.tolist())
        if any(len(used & set(c.image_vertices.tolist())) > 0.5 * len(used) for c in chosen):
            continue
        # one detection per object: none whose picture mostly covers a better one's
        outline = _outline(K, *to_cam(d.R, d.t), models[d.model])
        if any(_overlap(outline, o) > MAX_OVERLAP for o in outlines):
            continue
        chosen.append(d)
        outlines.append(outline)
        if len(chosen) == max_detections:
            break
    return chosen


#: Two detections whose pictures (the convex outlines of the projected models) overlap by
#: more than this share of the smaller one are one object: the better one is kept.
MAX_OVERLAP = 0.5


def _outline(K, R_cam, t_cam, model: Polyhedron) -> np.ndarray:
    """The convex outline `(k, 2)` float32 of `model`'s vertices projected at the pose."""
    uv = project_vertices(np.asarray(K), np.asarray(R_cam), np.asarray(t_cam), model.vertices)
    return cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2)


def _overlap(a: np.ndarray, b: np.ndarray) -> float:
    """The area shared by two convex outlines over the smaller one's area."""
    smaller = min(cv2.contourArea(a), cv2.contourArea(b))
    if smaller <= 0:
        return 0.0
    shared, _ = cv2.intersectConvexConvex(a, b)
    return float(shared) / smaller


@stored_jit(static_argnames=("confidence", "min_consensus"))
def _judge(C, model, image, mask, R, t, noise, confidence: float, min_consensus: float):
    """The acceptance rule of `verify` (Eq. 8 error and consensus against the
    chi-square bounds of `acceptance_thresholds`) at the poses `(H, 3, 3)`, `(H, 3)`
    that the linear method reaches from the refined ones: `(R, t, error, inliers,
    accepted, status)`, batched."""
    obs, R1, t1, error, status = _linear(C, model, image, mask, R, t)

    def rule(obs, R, t, error, status):
        solved = status == Status.OK
        status = jnp.where(solved, Status.ACCEPTED_LINEAR, status)
        accepted, status, inliers, *_ = verdict(
            obs, Pose(R, t), error, solved, status, noise, confidence, min_consensus
        )
        return inliers, accepted, status

    inliers, accepted, status = jax.vmap(rule)(obs, R1, t1, error, status)
    return R1, t1, error, inliers, accepted, status


def _verify_rows(C, rows, models, points, noise, V, Hn, poses):
    """The acceptance rule on every row `(name, model vertices, image vertices)` from its
    pose in `poses` (world frame), in one call, rows padded to `V` matches and `Hn`
    rows; rows with fewer than 4 matches come back rejected."""
    model, image, mask = _padded(rows, models, points, V, Hn)
    R = np.concatenate([poses[0], np.repeat(poses[0][:1], Hn - len(rows), 0)])
    t = np.concatenate([poses[1], np.repeat(poses[1][:1], Hn - len(rows), 0)])
    with jax.enable_x64(True):
        out = _judge(
            np.asarray(C, np.float64),
            np.asarray(model, np.float64),
            np.asarray(image, np.float64),
            np.asarray(mask),
            np.asarray(R, np.float64),
            np.asarray(t, np.float64),
            np.asarray(noise, np.float64),
            0.999,
            0.8,
        )
        out = [np.asarray(a) for a in out]
    result = []
    for r, (_, mv, _) in enumerate(rows):
        k = len(mv)
        result.append(
            (
                out[0][r],
                out[1][r],
                float(out[2][r]),
                out[3][r, :k],
                bool(out[4][r]) and k >= 4,
                Status(int(out[5][r])),
            )
        )
    return result
