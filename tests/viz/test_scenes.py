"""Rendered test scenes: ground truth consistent with the image, occlusion, clutter only,
determinism and argument checks."""

from __future__ import annotations

import cv2
import jax
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.viz import RenderedScene, rendered_scene

DATABASE = jp.apps.model_database()
# Compiled once per vertex count, not op by op.
_project_with_depth = jax.jit(jp.geometry.project_with_depth)


@pytest.mark.parametrize("name", list(DATABASE))
def test_model_in_frame_at_true_pose(name):
    scene = rendered_scene(11, DATABASE, model=name, occlusion=(0.0, 0.0))
    assert isinstance(scene, RenderedScene)
    assert scene.image.shape == (480, 640, 3) and scene.image.dtype == np.uint8
    assert scene.camera.shape == (3, 4) and scene.model == name
    model = DATABASE[name]
    assert scene.R is not None and scene.t is not None
    np.testing.assert_allclose(scene.R @ scene.R.T, np.eye(3), atol=1e-12)
    # The pixels are the camera's projections of the posed vertices.
    pixels, depth = _project_with_depth(scene.camera, model.vertices @ scene.R.T + scene.t)
    np.testing.assert_allclose(scene.pixels, np.asarray(pixels), atol=1e-6)
    assert np.all(np.asarray(depth) > 0)
    lo, hi = scene.pixels.min(axis=0), scene.pixels.max(axis=0)
    assert np.all(lo >= 0) and np.all(hi <= [639, 479])
    assert 130 <= np.max(hi - lo) <= 360
    # Without occluder every vertex the camera sees is visible, and at least three.
    seen = jp.apps._polyhedron.seen_vertices(model, scene.R, scene.t, np.zeros(3))
    assert np.array_equal(np.flatnonzero(scene.visible), seen) and len(seen) >= 3


def test_model_is_drawn_where_projected():
    # The model's silhouette, filled from the true pixels, differs from the background.
    scene = rendered_scene(4, DATABASE, model="box", occlusion=(0, 0), clutter=0, noise=0.0)
    model = DATABASE["box"]
    hull = cv2.convexHull(scene.pixels.astype(np.float32)).astype(np.int32)
    inside = np.zeros(scene.image.shape[:2], np.uint8)
    cv2.fillPoly(inside, [hull], 1)
    ring = cv2.dilate(inside, np.ones((21, 21), np.uint8)) - cv2.dilate(inside, np.ones((9, 9)))
    core = cv2.erode(inside, np.ones((9, 9), np.uint8))
    grey = cv2.cvtColor(scene.image, cv2.COLOR_BGR2GRAY).astype(float)
    assert grey[core > 0].mean() > grey[ring > 0].mean() + 40
    assert len(model.vertices) == len(scene.pixels) == len(scene.visible)


def test_occluder_hides_part_of_the_model():
    hidden = []
    for seed in range(6):
        clear = rendered_scene(seed, DATABASE, model="cross_prism", occlusion=(0.0, 0.0))
        partly = rendered_scene(seed, DATABASE, model="cross_prism", occlusion=(0.2, 0.3))
        np.testing.assert_allclose(clear.pixels, partly.pixels)
        assert not np.any(partly.visible & ~clear.visible)
        hidden.append(int(np.sum(clear.visible & ~partly.visible)))
    assert sum(hidden) >= 6


def test_clutter_only_scene():
    scene = rendered_scene(3, DATABASE, model=None, image_size=(320, 240))
    assert scene.image.shape == (240, 320, 3) and scene.model is None
    assert scene.R is None and scene.t is None
    assert scene.pixels.shape == (0, 2) and scene.visible.shape == (0,)
    assert scene.image.std() > 5


def test_deterministic_given_seed():
    a = rendered_scene(7, DATABASE, model="l_block")
    b = rendered_scene(7, DATABASE, model="l_block")
    c = rendered_scene(8, DATABASE, model="l_block")
    assert np.array_equal(a.image, b.image) and np.array_equal(a.pixels, b.pixels)
    assert not np.array_equal(a.image, c.image)


def test_noise_and_blur_options():
    clean = rendered_scene(2, DATABASE, model="pyramid", noise=0.0, blur=0.0)
    noisy = rendered_scene(2, DATABASE, model="pyramid", noise=8.0, blur=0.0)
    diff = noisy.image.astype(float) - clean.image
    assert 6 < diff.std() < 10


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"seed": -1}, "seed"),
        ({"seed": 1.5}, "seed"),
        ({"database": {"a": 1}}, "database"),
        ({"model": "sphere"}, "model"),
        ({"occlusion": (0.3, 0.1)}, "occlusion"),
        ({"occlusion": 0.2}, "occlusion"),
        ({"clutter": -2}, "clutter"),
        ({"noise": -1.0}, "noise"),
        ({"blur": float("nan")}, "blur"),
        ({"image_size": (10, 10)}, "image_size"),
        ({"image_size": "big"}, "image_size"),
    ],
)
def test_bad_arguments_raise(kwargs, name):
    args = {"seed": 0, "database": DATABASE} | kwargs
    seed, database = args.pop("seed"), args.pop("database")
    with pytest.raises(ValueError, match=name):
        rendered_scene(seed, database, **args)
