"""Recognition without correspondences (`jaxpose.apps.detect`): the right model and pose
from an image's primitives alone, nothing from clutter, the compiled scoring's poses
equal to the reference three-point solver's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.apps._bench import random_rotation
from jaxpose.apps._detect import _paths, _tables
from jaxpose.apps._detect_edges import project_vertices
from jaxpose.apps._hypotheses import score_paths
from jaxpose.apps._polyhedron import seen_vertices
from jaxpose.features import Primitives, Segments, Vertices, edge_distance

NAMES = ("cross_prism", "l_block", "hexagonal_prism")
K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
C = K @ np.eye(3, 4)
SIZE = (480, 640)


@pytest.fixture(scope="module")
def database():
    db = jp.apps.model_database()
    return {name: db[name] for name in NAMES}


def _pose(rng, model):
    while True:
        R = random_rotation(rng)
        t = np.array([rng.uniform(-50, 50), rng.uniform(-30, 30), rng.uniform(450, 650)])
        uv = project_vertices(K, R, t, model.vertices)
        if uv.min() > 30 and uv[:, 0].max() < 610 and uv[:, 1].max() < 450:
            return R, t, uv


def _primitives(rng, model=None, clutter: int = 12, noise: float = 0.3) -> tuple:
    """Ideal primitives: the seen vertices and edges of `model` (pixels with noise) and
    `clutter` random segments meeting at random corners."""
    points, ends, links = [], [], []
    R = t = uv = None
    if model is not None:
        R, t, uv = _pose(rng, model)
        seen = seen_vertices(model, R, t, np.zeros(3)).tolist()
        index = {v: i for i, v in enumerate(seen)}
        points = [uv[v] + rng.normal(scale=noise, size=2) for v in seen]
        for a, b in np.asarray(model.edges):
            if a in index and b in index:
                ends.append((points[index[a]], points[index[b]]))
                links.append((index[a], index[b]))
    base = len(points)
    corners = rng.uniform([20, 20], [620, 460], size=(clutter, 2))
    for k in range(clutter):
        points.append(corners[k])
        for _ in range(2):
            d = rng.normal(size=2)
            ends.append((corners[k], corners[k] + rng.uniform(20, 80) * d / np.hypot(*d)))
    P = np.array(points).reshape(-1, 2)
    E = np.array(ends).reshape(-1, 2, 2)
    incident = np.full((len(P), 3), -1)
    for s, (a, b) in enumerate(E):
        for v in range(len(P)):
            if min(np.hypot(*(a - P[v])), np.hypot(*(b - P[v]))) < 1e-9:
                row = incident[v]
                free = np.flatnonzero(row < 0)
                if len(free):
                    row[free[0]] = s
    L = np.zeros((len(P), len(P)), bool)
    for a, b in links:
        L[a, b] = L[b, a] = True
    segments = Segments(E, np.ones(len(E)), np.ones(len(E)))
    vertices = Vertices(P, np.tile(np.eye(2), (len(P), 1, 1)), incident, np.ones(len(P)))
    prim = Primitives(segments, vertices, L, edge_distance(segments, SIZE))
    return prim, R, t, uv, base


def test_ideal_primitives_give_the_model_and_its_pose(database):
    rng = np.random.default_rng(3)
    for name in NAMES:
        prim, R, t, uv, _ = _primitives(rng, database[name])
        found = jp.apps.detect(C, prim, database)
        assert found, name
        best = found[0]
        assert best.model == name
        got = project_vertices(K, best.R, best.t, database[name].vertices)
        error = np.min(np.linalg.norm(uv[:, None] - got[None], axis=-1), axis=1)
        assert np.sqrt(np.mean(error**2)) < 1.0, name  # (symmetric poses count as right)
        assert 0 < best.support <= 1 and best.score > 0
        assert np.all(np.isfinite(best.R)) and np.all(np.isfinite(best.t))
        assert len(best.vertices) == len(best.image_vertices) == len(best.pixels) >= 4


def test_clutter_alone_gives_nothing(database):
    rng = np.random.default_rng(5)
    for _ in range(3):
        prim, *_ = _primitives(rng, None, clutter=25)
        assert jp.apps.detect(C, prim, database) == []


def test_rendered_scenes(database):
    """A rendered, occluded, cluttered scene through the image front end; a scene without
    the model gives no detection."""
    scene = jp.viz.rendered_scene(2, database, model="cross_prism")
    found = jp.apps.detect(scene.camera, jp.features.image_primitives(scene.image), database)
    assert found and found[0].model == "cross_prism"
    got = project_vertices(K, found[0].R, found[0].t, database["cross_prism"].vertices)
    error = np.min(np.linalg.norm(scene.pixels[:, None] - got[None], axis=-1), axis=1)
    assert np.sqrt(np.mean(error**2)) < 2.0
    empty = jp.viz.rendered_scene(1002, database, model=None)
    assert jp.apps.detect(empty.camera, jp.features.image_primitives(empty.image), database) == []


def test_scoring_kernel_finds_the_true_pose(database):
    """The compiled pass: the best of the true pairings' roots is the true pose (to
    float32 rounding), and it scores most of what it predicts as held (the kernel's
    visibility is the convex test, so a non-convex model's hidden parts count as seen)."""
    model = database["l_block"]
    rng = np.random.default_rng(0)
    prim, R, t, uv, _ = _primitives(rng, model, clutter=0, noise=0.0)
    paths = _paths(model)
    rays = np.column_stack([uv, np.ones(len(uv))]) @ np.linalg.inv(K).T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    seen = set(seen_vertices(model, R, t, np.zeros(3)).tolist())
    use = np.array([all(v in seen for v in p) for p in paths])
    size = 64
    chosen = paths[use][:size]
    bearings = np.zeros((size, 3, 3), np.float32)
    points = np.zeros((size, 3, 3), np.float32)
    bearings[: len(chosen)] = rays[chosen]
    points[: len(chosen)] = model.vertices[chosen]
    mask = (np.arange(size) < len(chosen)).astype(np.float32)
    vdist = np.full(SIZE, 1e3, np.float32)
    for p in prim.vertices.points:
        vdist[int(p[1]), int(p[0])] = 0.0
    edist = np.stack([edge_distance(prim.segments, SIZE)] * 8)
    out = score_paths(
        jnp.asarray(K, jnp.float32),
        jnp.asarray(bearings),
        jnp.asarray(points),
        jnp.asarray(mask),
        _tables(model, 16, 16, 24),
        jnp.asarray(vdist.reshape(-1)),
        jnp.asarray(edist.reshape(-1)),
        jnp.float32(1.5),
        jnp.float32(1.5),
        jnp.float32(10.0),
        width=SIZE[1],
        height=SIZE[0],
        top=4,
    )
    out = jax.tree.map(np.asarray, out)
    assert np.all(np.isfinite(out.R)) and np.all(np.isfinite(out.t))
    best = int(np.argmax(out.score))
    np.testing.assert_allclose(out.R[best], R, atol=2e-4)
    np.testing.assert_allclose(out.t[best], t, rtol=2e-4)
    assert 0.8 * out.seen[best] <= out.score[best] <= out.seen[best]


def test_bad_arguments(database):
    rng = np.random.default_rng(0)
    prim, *_ = _primitives(rng, database["l_block"], clutter=0)
    with pytest.raises(ValueError, match="camera"):
        jp.apps.detect(np.eye(3), prim, database)
    with pytest.raises(ValueError, match="database"):
        jp.apps.detect(C, prim, {})
    with pytest.raises(ValueError, match="primitives"):
        jp.apps.detect(C, object(), database)
    with pytest.raises(ValueError, match="noise"):
        jp.apps.detect(C, prim, database, noise=-1.0)
    with pytest.raises(ValueError, match="candidates"):
        jp.apps.detect(C, prim, database, candidates=0)
    with pytest.raises(ValueError, match="min_support"):
        jp.apps.detect(C, prim, database, min_support=2.0)


def test_edges_pull_a_pose_onto_the_segments(database):
    """`refine_on_edges`: from a pose a few pixels off, segments drawn exactly along the
    seen edges and no vertex give back the true pose; without segments the pose stays."""
    from jaxpose.apps._detect_edges import refine_on_edges
    from jaxpose.geometry import rotvec_to_matrix

    model = database["l_block"]
    rng = np.random.default_rng(4)
    prim, R, t, uv, base = _primitives(rng, model, clutter=0, noise=0.0)
    with jax.enable_x64(True):
        nudge = np.asarray(rotvec_to_matrix(jnp.array([0.01, -0.008, 0.005])))
    R0, t0 = nudge @ R, t + np.array([1.0, -1.5, 4.0])
    none = np.zeros(0, np.int64)
    R1, t1 = refine_on_edges(K, R0, t0, model, none, np.zeros((0, 2)), prim.segments.ends)
    error = np.linalg.norm(project_vertices(K, R1, t1, model.vertices) - uv, axis=1)
    start = np.linalg.norm(project_vertices(K, R0, t0, model.vertices) - uv, axis=1)
    assert np.max(start) > 2 and np.max(error) < 1e-3
    R2, t2 = refine_on_edges(K, R0, t0, model, none, np.zeros((0, 2)), np.zeros((0, 2, 2)))
    np.testing.assert_array_equal(R2, R0)
    np.testing.assert_array_equal(t2, t0)


def test_overlapping_pictures_are_one_object():
    """Two poses of one model whose pictures mostly cover each other count as one object
    (`detect` keeps the better), side by side as two."""
    from jaxpose.apps._detect_verify import MAX_OVERLAP, _outline, _overlap

    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    model = jp.apps.read_ply(jp.apps.sample_path("opencv_pose_box", "box.ply"))  # 26 cm
    here = _outline(K, np.eye(3), np.array([0.0, 0, 100]), model)
    nudged = _outline(K, np.eye(3), np.array([1.0, 0, 102]), model)
    beside = _outline(K, np.eye(3), np.array([80.0, 0, 100]), model)
    assert _overlap(here, here) == pytest.approx(1.0)
    assert _overlap(here, nudged) > MAX_OVERLAP
    assert _overlap(here, beside) == 0.0
