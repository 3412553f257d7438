"""The solver's options (`jaxpose.Options`, `jaxpose.RobustOptions`): one default per
field, hashable (static arguments of `jax.jit`), checked when made, and the keyword
shorthands of the entry points."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.strategy._options import resolve


def test_defaults():
    o = jp.Options()
    assert o.method == "mixed" and o.threshold is None and o.rel_threshold == 0.01
    assert (o.min_area, o.collinear_tol) == (0.0138, 5e-3)
    assert (o.linear_iterations, o.nonlinear_budget, o.max_steps) == (5, 32, 50)
    assert (o.second_chance_budget, o.planar_partner) == (8, True)
    assert (o.max_triplets, o.triplet_budget, o.chunk) == (2000, None, None)
    r = jp.RobustOptions()
    assert (r.inlier_threshold, r.min_inliers, r.refine, r.rounds) == (8.0, 4, "linear", 2)
    # The settings robust mode shares with Options have Options' defaults.
    assert (r.iterations, r.max_steps) == (o.linear_iterations, o.max_steps)
    assert (r.min_area, r.collinear_tol, r.max_triplets) == (
        o.min_area,
        o.collinear_tol,
        o.max_triplets,
    )
    assert jp.api.METHODS == ("mixed", "three_point", "linear", "nonlinear")


def test_frozen_and_hashable():
    a, b = jp.Options(method="linear", threshold=2.0), jp.Options(method="linear", threshold=2.0)
    assert a == b and hash(a) == hash(b) and a != jp.Options()
    assert len({a, b, jp.Options()}) == 2
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.method = "mixed"
    assert hash(jp.RobustOptions(refine="none")) == hash(jp.RobustOptions(refine="none"))


def test_options_are_a_static_argument_of_jit():
    rng = np.random.default_rng(0)
    s = jp.apps.random_scene(rng, 6, noise=0.5)
    C, M, I = (jnp.asarray(x) for x in (s.camera, s.model_points, s.image_points))
    run = jax.jit(jp.solve, static_argnames="options")
    options = jp.Options(method="three_point", threshold=5.0)
    via_options = run(C, M, I, options=options)
    via_keywords = jax.jit(lambda C, M, I: jp.solve(C, M, I, method="three_point", threshold=5.0))(
        C, M, I
    )
    for a, b in zip(jax.tree.leaves(via_options), jax.tree.leaves(via_keywords), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert bool(via_options.accepted)
    # An equal options object reuses the compiled program.
    before = run._cache_size()
    run(C, M, I, options=jp.Options(method="three_point", threshold=5.0))
    assert run._cache_size() == before


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("method", "p3p"),
        ("method", "MIXED"),
        ("threshold", 0.0),
        ("threshold", float("nan")),
        ("threshold", "2"),
        ("rel_threshold", -0.1),
        ("min_area", float("inf")),
        ("collinear_tol", -1.0),
        ("linear_iterations", 0),
        ("linear_iterations", 2.0),
        ("nonlinear_budget", -1),
        ("nonlinear_budget", True),
        ("second_chance_budget", -1),
        ("planar_partner", 1),
        ("max_steps", 0),
        ("max_triplets", 0),
        ("triplet_budget", 0),
        ("triplet_budget", 1.5),
        ("triplet_budget", "8"),
        ("chunk", 0),
    ],
)
def test_bad_values_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        jp.Options(**{field: value})
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(jp.Options(), **{field: value})


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("inlier_threshold", 0.0),
        ("min_inliers", 2),
        ("min_inliers", 4.5),
        ("refine", "ransac"),
        ("rounds", -1),
        ("iterations", 0),
        ("max_steps", 0),
        ("max_triplets", 0),
    ],
)
def test_bad_robust_values_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        jp.RobustOptions(**{field: value})


def test_keyword_shorthands():
    base = jp.Options(method="linear")
    assert resolve(base, {"threshold": 2.0}) == jp.Options(method="linear", threshold=2.0)
    assert resolve(None, {}) == jp.Options()
    assert resolve(base, {}) is base
    assert resolve(None, {"refine": "none"}, jp.RobustOptions) == jp.RobustOptions(refine="none")
    with pytest.raises(ValueError, match="'nonlinear_budjet'"):
        resolve(None, {"nonlinear_budjet": 4})
    with pytest.raises(ValueError, match="options must be a jaxpose.Options"):
        resolve({"method": "linear"}, {})
    with pytest.raises(ValueError, match="options must be a jaxpose.RobustOptions"):
        resolve(jp.Options(), {}, jp.RobustOptions)


def test_entry_points_reject_unknown_keywords():
    """Every entry point resolves its options first: an unknown keyword raises at once,
    naming it, before any input is read or anything compiled."""
    s = jp.apps.random_scene(np.random.default_rng(1), 6, world_camera=False)
    C, M, I = (jnp.asarray(x) for x in (s.camera, s.model_points, s.image_points))
    K = s.camera[:, :3]  # the camera frame is the world frame: C = K [I | 0]
    obs = jp.observations(C, M, I)
    calls = [
        lambda: jp.solve(C, M, I, mehtod="linear"),
        lambda: jp.solve_many(C, M[None], I[None], mehtod="linear"),
        lambda: jp.solve_batch(s.camera, s.model_points[None], s.image_points[None], mehtod="x"),
        lambda: jp.solve_pnp(s.model_points, s.image_points, K, mehtod="linear"),
        lambda: jp.solve_pnp_batch(s.model_points[None], s.image_points[None], K, mehtod="x"),
        lambda: jp.solve_pnp_ransac(s.model_points, s.image_points, K, mehtod="linear"),
        lambda: jp.robust(C, M, I, mehtod="linear"),
        lambda: jp.mixed(obs, mehtod="linear"),
        lambda: jp.strategy.initial_poses(obs, mehtod="linear"),
    ]
    for call in calls:
        with pytest.raises(ValueError, match="unknown option 'mehtod'"):
            call()
    with pytest.raises(ValueError, match="method"):
        jp.solve(C, M, I, options=jp.Options(), method="sqpnp")


def test_options_are_four_groups_by_concern():
    """`Options` is made of its groups (selection, search, acceptance, execution), from
    groups or single settings alike; a setting reads through and overrides its group."""
    by_groups = jp.Options(
        acceptance=jp.Acceptance(threshold=2.0), search=jp.Search(method="linear")
    )
    by_settings = jp.Options(threshold=2.0, method="linear")
    assert by_groups == by_settings and hash(by_groups) == hash(by_settings)
    assert by_groups.acceptance.threshold == by_groups.threshold == 2.0
    assert by_groups.search.method == "linear" and by_groups.selection == jp.Selection()
    assert by_groups.execution == jp.Execution()
    # A setting given beside its group overrides that field of the group only.
    o = jp.Options(search=jp.Search(method="linear", max_steps=7), max_steps=9)
    assert (o.method, o.max_steps) == ("linear", 9)
    # `dataclasses.replace` takes settings and groups.
    assert dataclasses.replace(o, min_area=0.5).selection.min_area == 0.5
    assert dataclasses.replace(o, execution=jp.Execution(chunk=4)).chunk == 4
    # Every setting belongs to exactly one group, and the class reads the defaults.
    from jaxpose.strategy._options import GROUP_OF

    groups = (jp.Selection, jp.Search, jp.Acceptance, jp.Execution)
    names = [f.name for g in groups for f in dataclasses.fields(g)]
    assert len(names) == len(set(names)) == len(GROUP_OF) == 19
    assert all(getattr(jp.Options, n) == getattr(jp.Options(), n) for n in names)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"acceptance": jp.Search()}, "acceptance"),
        ({"selection": {"min_area": 1.0}}, "selection"),
        ({"spread": 4}, "spread"),
    ],
)
def test_bad_groups_are_named(kwargs, name):
    with pytest.raises(ValueError, match=name):
        jp.Options(**kwargs)
    with pytest.raises(ValueError, match=name):
        resolve(None, kwargs)


def test_groups_check_their_settings():
    with pytest.raises(ValueError, match="rel_threshold"):
        jp.Acceptance(rel_threshold=-1.0)
    with pytest.raises(ValueError, match="wider_spread"):
        jp.Selection(wider_spread=2)
    with pytest.raises(ValueError, match="derivative"):
        jp.Execution(derivative=1)
