import itertools

import jax
import numpy as np
import pytest

import jaxpose as jp

# Jitted: one program per shape rather than one per eager operation.
_project = jax.jit(jp.project)
_project_with_depth = jax.jit(jp.geometry.project_with_depth)


def test_cross_prism_topology():
    model = jp.apps.cross_prism()
    assert model.vertices.shape == (24, 3)
    assert model.edges.shape == (36, 2)
    assert len(model.faces) == 14
    extent = model.vertices.max(0) - model.vertices.min(0)
    np.testing.assert_allclose(extent, [155.0, 143.0, 20.0])
    # Euler characteristic of a genus-0 polyhedron: V - E + F = 2.
    assert 24 - 36 + 14 == 2
    # every edge is shared by exactly two faces, traversed in opposite directions
    directed = [(f[i], f[(i + 1) % len(f)]) for f in model.faces for i in range(len(f))]
    assert len(directed) == len(set(directed)) == 72
    assert all((b, a) in directed for a, b in directed)
    assert {tuple(sorted(e)) for e in model.edges.tolist()} == {tuple(sorted(d)) for d in directed}


def test_faces_point_outwards():
    # Divergence theorem: with outward (counter-clockwise from outside) faces the signed
    # volume is positive and equals the cross's area times its thickness.
    model = jp.apps.cross_prism()
    volume = 0.0
    for face in model.faces:
        p = model.vertices[list(face)]
        for i in range(1, len(face) - 1):
            volume += p[0] @ np.cross(p[i], p[i + 1]) / 6
    area = 47 * 143 + 155 * 51 - 47 * 51
    assert volume == pytest.approx(area * 20.0)


def test_default_bench_matches_the_paper_setup():
    b = jp.default_bench()
    assert b.model_points.shape == (16, 3) and b.image_points.shape == (16, 2)
    assert len(set(b.visible.tolist())) == 16
    world = b.model_points @ b.R.T + b.t
    centre = -np.linalg.solve(b.camera[:, :3], b.camera[:, 3])
    distance = np.linalg.norm(world - centre, axis=1)
    assert 1900 < distance.mean() < 2100  # about 2 m
    w, h = b.image_size
    assert (w, h) == (768, 576)
    assert np.all((b.clean_points > 0) & (b.clean_points < [w, h]))
    np.testing.assert_allclose(_project(b.camera, world), b.clean_points, atol=1e-9)
    residual = b.image_points - b.clean_points
    assert 0.4 < residual.std() < 1.2  # seeded Gaussian noise of b.noise px

    def area(i, j, k):
        (x1, y1), (x2, y2) = (
            b.image_points[j] - b.image_points[i],
            b.image_points[k] - b.image_points[i],
        )
        return 0.5 * abs(x1 * y2 - x2 * y1)

    areas = [area(*ijk) for ijk in itertools.combinations(range(16), 3)]
    assert 5 < np.sum(np.array(areas) < 40) < 40  # the paper: 32 aligned of 560


def test_bench_is_seeded():
    a, b = jp.default_bench(seed=1), jp.default_bench(seed=1)
    np.testing.assert_array_equal(a.image_points, b.image_points)
    assert not np.allclose(a.image_points, jp.default_bench(seed=2).image_points)
    np.testing.assert_array_equal(
        jp.default_bench(noise=0.0).image_points, jp.default_bench(noise=0.0).clean_points
    )


@pytest.mark.parametrize("kind", ["ordinary", "quasi_singular", "planar"])
def test_random_scene(kind):
    rng = np.random.default_rng(3)
    s = jp.apps.random_scene(rng, 12, noise=0.0, kind=kind)
    world = s.model_points @ s.R.T + s.t
    np.testing.assert_allclose(_project(s.camera, world), s.image_points, atol=1e-8)
    _, depth = _project_with_depth(s.camera, world)
    assert np.all(np.asarray(depth) > 3.9)
    assert np.linalg.det(s.R) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="kind"):
        jp.apps.random_scene(rng, 5, kind="bogus")
