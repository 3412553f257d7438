r"""Recognition without correspondences, the compiled part: every pairing of an image
path with a model path solved by the three-point method and every root scored against
the image, in one batch-first, fixed-shape pass per chunk.

A *path* is three vertices joined by two edges, `(i, j, k)` with `j` in the middle. An
image path (vertices linked by detected segments) paired with a model path (vertices
joined by model edges) is a hypothesis for three matches: `p3p_components` gives up to
four poses (model to camera frame). Each pose is scored by what the model predicts
and the image holds:

- the model's vertices on a face turned towards the camera (a convex-hull test: a
  vertex is seen when one of its faces is front-facing) and inside the image, each a
  hit when an image vertex lies within `vertex_radius` px of its projection (one gather
  from the image's vertex-distance map);
- the model's edges on a front-facing face, sampled at `S` points each; a sample is
  covered when a detected segment passes within `edge_radius` px (one gather from the
  image's edge-distance map).

The score is `hits + covered`, where `covered` sums over the seen edges the fraction
of each edge's samples that are covered; the seen counts are returned beside it, so
that the caller can judge how much of its prediction a pose explains. Every vector is
three arrays (component form): the poses are `(C, 4)` arrays, the projected vertices
`(C, 4, V)`, the edge samples `(C, 4, E * S)`; the face tests are one matrix product
`(C * 4, 3) x (3, F)`, the incidences one `(C * 4, F) x (F, V)`. Each chunk returns its
`top` best poses only.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..api._programs import stored_jit
from ..solvers._components import Vec3
from ..solvers._kernel_p3p import p3p_components

__all__ = ["ModelTables", "Scored", "score_paths"]


class ModelTables(NamedTuple):
    """One model's arrays for the scoring kernel, padded to common sizes (masks say
    which rows are real).

    **Fields:** `vertices` `(V, 3)`, `vertex_mask` `(V,)`; `normals` `(F, 3)` outward
    unit normals and `offsets` `(F,)` (`n . p` for a point `p` of the face), unused
    faces with a zero normal and offset 1 (never front-facing); `vertex_faces` `(V, F)`
    and `edge_faces` `(E, F)` incidences (0/1); `samples` `(E, S, 3)` points along each
    edge; `edge_mask` `(E,)`; `edge_vertices` `(E, V)` the edges' two end points (0/1).
    """

    vertices: Float[Array, "V 3"]
    vertex_mask: Float[Array, " V"]
    normals: Float[Array, "F 3"]
    offsets: Float[Array, " F"]
    vertex_faces: Float[Array, "V F"]
    edge_faces: Float[Array, "E F"]
    samples: Float[Array, "E S 3"]
    edge_mask: Float[Array, " E"]
    edge_vertices: Float[Array, "E V"]


class Scored(NamedTuple):
    """The `top` best poses of a chunk: `score`, `seen` (seen vertices + seen edges),
    `pair` (the pair's row in the chunk), `R` `(top, 3, 3)`, `t` `(top, 3)` (model to
    camera frame); rows without a valid pose have score `-1`."""

    score: Float[Array, " top"]
    seen: Float[Array, " top"]
    pair: Int[Array, " top"]
    R: Float[Array, "top 3 3"]
    t: Float[Array, "top 3"]


def _gather(distance, u, v, width: int, height: int, offset: Array | int = 0):
    """The map's value at pixel `(u, v)` (nearest pixel; `offset` selects a map of a
    stack), `inf` outside the image."""
    inside = (u >= 0) & (v >= 0) & (u < width) & (v < height)
    iu = jnp.clip(jnp.floor(u), 0, width - 1).astype(jnp.int32)
    iv = jnp.clip(jnp.floor(v), 0, height - 1).astype(jnp.int32)
    return jnp.where(inside, distance[offset + iv * width + iu], jnp.inf)


def _signs(incidence):
    """`+1` on each row's first end point, `-1` on its second (rows of an `(E, V)` 0/1
    incidence), so that the incidence times the signs takes differences."""
    first = jnp.cumsum(incidence, axis=1) == 1
    return jnp.where(first, 1, -1).astype(incidence.dtype)


def _project(K, R, t, x, y, z):
    """Pixels and depth of model points `(x, y, z)` `(C, 1, N)` under poses `(C, 4, 1)`."""
    X = R[0] * x + R[1] * y + R[2] * z + t.x
    Y = R[3] * x + R[4] * y + R[5] * z + t.y
    Z = R[6] * x + R[7] * y + R[8] * z + t.z
    inv = 1 / jnp.where(Z > 0, Z, 1)
    u = K[0, 0] * X * inv + K[0, 1] * Y * inv + K[0, 2]
    v = K[1, 1] * Y * inv + K[1, 2]
    return u, v, Z > 0


@stored_jit(static_argnames=("width", "height", "top"))
def score_paths(
    K: Float[Array, "3 3"],
    bearings: Float[Array, "C 3 3"],
    points: Float[Array, "C 3 3"],
    pair_mask: Float[Array, " C"],
    tables: ModelTables,
    vertex_distance: Float[Array, " HW"],
    edge_distance: Float[Array, " BHW"],
    vertex_radius: Float[Array, ""],
    edge_radius: Float[Array, ""],
    min_edge: Float[Array, ""],
    *,
    width: int,
    height: int,
    top: int,
) -> Scored:
    """Solve and score `C` path pairings of one model (see the module docstring).

    **Arguments:**
    - `K`: the camera's intrinsics (upper triangular, `K[2, 2] = 1`).
    - `bearings`: `(C, 3, 3)` the image path's rays `K^-1 (u, v, 1)` (camera frame).
    - `points`: `(C, 3, 3)` the model path's vertices.
    - `pair_mask`: `(C,)` 1 for real pairings (the rest is padding).
    - `tables`: the model's `ModelTables`.
    - `vertex_distance`: `(height * width,)`, row-major: the distance (px) from each
      pixel to the nearest image vertex; `edge_distance`: `(bins * height * width,)`,
      `bins` such maps to the nearest detected segment of each direction bin
      (`jaxpose.features.oriented_edge_distance`); a predicted edge looks up its own.
    - `vertex_radius`, `edge_radius`: hit radii (px); `min_edge`: the shortest edge (px)
      that counts.
    - `width`, `height`: the maps' size; `top`: poses kept.

    **Returns:** `Scored`.
    """
    dtype = bearings.dtype

    def triple(a) -> tuple[Vec3, Vec3, Vec3]:
        v0, v1, v2 = (Vec3(a[:, i, 0], a[:, i, 1], a[:, i, 2]) for i in range(3))
        return v0, v1, v2

    cand = p3p_components(triple(bearings), triple(points))
    valid = cand.real & cand.positive & (pair_mask[:, None] > 0)
    R = tuple(r[..., None] for r in cand.R)  # nine (C, 4, 1)
    t = Vec3(*(c[..., None] for c in cand.t))
    # Camera centre in the model frame, o = -R^T t, and the front-facing faces.
    ox = -(R[0] * t.x + R[3] * t.y + R[6] * t.z)[..., 0]
    oy = -(R[1] * t.x + R[4] * t.y + R[7] * t.z)[..., 0]
    oz = -(R[2] * t.x + R[5] * t.y + R[8] * t.z)[..., 0]
    centre = jnp.stack([ox, oy, oz], axis=-1)  # (C, 4, 3)
    front = (jnp.einsum("cpk,fk->cpf", centre, tables.normals) > tables.offsets[None, None]).astype(
        dtype
    )
    seen_v = jnp.einsum("cpf,vf->cpv", front, tables.vertex_faces * tables.vertex_mask[:, None])
    seen_e = jnp.einsum("cpf,ef->cpe", front, tables.edge_faces * tables.edge_mask[:, None])
    seen_v, seen_e = seen_v > 0, seen_e > 0

    m = tables.vertices
    u, v, ahead = _project(K, R, t, *(m[None, None, :, i] for i in range(3)))
    d = _gather(vertex_distance, u, v, width, height)
    # An edge counts when seen and at least `min_edge` px long in the image (a pose that
    # shrinks the model onto a few image features explains nothing); a vertex when it
    # ends a counted edge and lies in the image.
    du = jnp.einsum("cpv,ev->cpe", u, tables.edge_vertices * _signs(tables.edge_vertices))
    dv = jnp.einsum("cpv,ev->cpe", v, tables.edge_vertices * _signs(tables.edge_vertices))
    seen_e = seen_e & (du * du + dv * dv >= min_edge * min_edge)
    ends = jnp.einsum("cpe,ev->cpv", seen_e.astype(dtype), tables.edge_vertices) > 0
    seen_v = seen_v & ends & ahead & jnp.isfinite(d)
    hits = jnp.sum(seen_v & (d <= vertex_radius), axis=-1)

    E, S = tables.samples.shape[:2]
    bins = edge_distance.shape[0] // (width * height)
    angle = jnp.mod(jnp.arctan2(dv, du), jnp.pi)
    which = jnp.clip(jnp.floor(angle * (bins / jnp.pi)), 0, bins - 1).astype(jnp.int32)
    offset = jnp.repeat(which * (width * height), S, axis=-1)  # (C, 4, E * S)
    s = tables.samples.reshape(E * S, 3)
    u, v, ahead = _project(K, R, t, *(s[None, None, :, i] for i in range(3)))
    covered = (_gather(edge_distance, u, v, width, height, offset) <= edge_radius) & ahead
    fraction = jnp.mean(covered.reshape(*covered.shape[:2], E, S).astype(dtype), axis=-1)
    covered_e = jnp.sum(jnp.where(seen_e, fraction, 0), axis=-1)

    score = jnp.where(valid, hits.astype(dtype) + covered_e, -1)
    seen = (jnp.sum(seen_v, axis=-1) + jnp.sum(seen_e, axis=-1)).astype(dtype)
    flat = score.reshape(-1)
    best, index = jax.lax.top_k(flat, top)
    pair, slot = index // 4, index % 4
    Rm = jnp.stack([r[pair, slot] for r in cand.R], axis=-1).reshape(top, 3, 3)
    tv = jnp.stack([c[pair, slot] for c in cand.t], axis=-1)
    good = best >= 0
    Rm = jnp.where(good[:, None, None], Rm, jnp.eye(3, dtype=dtype)[None])
    tv = jnp.where(good[:, None], tv, 0)
    return Scored(best, seen.reshape(-1)[index], pair.astype(jnp.int32), Rm, tv)
