"""Sharded and chunked batches (`jaxpose.api.run_batched`, `solve_batch`, `solve_pnp_batch`).

The multi-device checks run in a subprocess with 8 forced CPU host devices
(`--xla_force_host_platform_device_count=8` in `XLA_FLAGS`, the other flags kept): this
process keeps one device (`conftest.py`). They compare, row by row, the sharded and
chunked paths with the plain single-device call.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.api._batch import _pad_rows
from jaxpose.api._solve import _argument_order

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TOL = 1e-12


def _run_child(code: str, out_dir, timeout: int = 900) -> dict:
    """Run `code` with 8 host devices; it saves its arrays to `out_dir/out.npz`."""
    env = {
        **os.environ,
        "XLA_FLAGS": " ".join(
            [f for f in os.environ.get("XLA_FLAGS", "").split() if "device_count" not in f]
            + ["--xla_force_host_platform_device_count=8"]
        ),
        "JAX_PLATFORMS": "cpu",
        "OUT": str(out_dir / "out.npz"),
    }
    proc = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    with np.load(out_dir / "out.npz") as data:
        return dict(data)


_SETUP = """
    import os
    import jax
    import numpy as np
    jax.config.update("jax_enable_x64", True)
    import jaxpose as jp

    assert jax.device_count() == 8, jax.devices()
    rng = np.random.default_rng(0)
    B, n = 37, 6  # not a multiple of 8 nor of the chunks: every path pads
    scenes = [jp.apps.random_scene(rng, n, noise=0.5, world_camera=world) for world in
              [False] * B]
    K = scenes[0].camera[:, :3]
    obj = np.stack([s.model_points for s in scenes])
    img = np.stack([s.image_points for s in scenes])
    obj[5] = obj[5, :1] + np.linspace(0, 1, n)[:, None] * (obj[5, 1] - obj[5, 0])  # collinear
    out = {}
"""


def _assert_same(out, reference, variants, fields):
    for variant in variants:
        for field in fields:
            a, b = out[f"{variant}_{field}"], out[f"{reference}_{field}"]
            assert a.shape == b.shape and a.dtype == b.dtype, (variant, field)
            if a.dtype == bool or np.issubdtype(a.dtype, np.integer):
                np.testing.assert_array_equal(a, b, err_msg=f"{variant} {field}")
            else:
                np.testing.assert_allclose(a, b, rtol=0, atol=TOL, err_msg=f"{variant} {field}")


def test_sharded_and_chunked_equal_single_device(tmp_path):
    """`solve_pnp_batch` (three-point method: quick to compile) and the JAX-native
    `solve_batch`, 8 devices and chunks versus one device, one call."""
    code = (
        _SETUP
        + """
    def pnp(name, **kw):
        ok, r, t = jp.solve_pnp_batch(obj, img, K, method="three_point", **kw)
        out.update({name + "_ok": ok, name + "_rvecs": r, name + "_tvecs": t})

    pnp("one", devices=1)
    pnp("one_chunked", devices=1, chunk_size=10)
    pnp("sharded_chunked", chunk_size=16)

    # JAX-native: world cameras, one per problem, and a mask.
    world = [jp.apps.random_scene(rng, n, noise=0.5) for _ in range(B)]
    C = np.stack([s.camera for s in world])
    m = np.stack([s.model_points for s in world])
    u = np.stack([s.image_points for s in world])
    mask = np.ones((B, n), bool)
    mask[3, :4] = False  # too few matches
    plain = jax.jit(jax.vmap(lambda c, a, b, k: jp.solve(c, a, b, k, method="three_point")))
    for name, sol in (
        ("vmap", plain(C, m, u, mask)),
        ("native", jp.solve_batch(C, m, u, mask, method="three_point", chunk_size=24)),
    ):
        for field, value in zip(("R", "t"), sol.pose):
            out[f"{name}_{field}"] = np.asarray(value)
        for field in ("error", "pose_error", "status", "accepted", "triplet"):
            out[f"{name}_{field}"] = np.asarray(getattr(sol, field))
    np.savez(os.environ["OUT"], **out)
    """
    )
    out = _run_child(code, tmp_path)
    _assert_same(out, "one", ["one_chunked", "sharded_chunked"], ["ok", "rvecs", "tvecs"])
    fields = ["R", "t", "error", "pose_error", "status", "accepted", "triplet"]
    _assert_same(out, "vmap", ["native"], fields)
    # The results are real: the collinear problem fails, the others are solved.
    assert not out["one_ok"][5] and np.sum(out["one_ok"]) == 36
    assert out["vmap_status"][3] == jp.Status.TOO_FEW_POINTS and np.sum(out["vmap_accepted"]) == 36


@pytest.mark.slow
def test_sharded_mixed_equals_single_device(tmp_path):
    """The default mixed method, 8 devices in chunks of 16 versus one device in one call.

    Every one of these problems is settled by the best roots (the first program): the
    fallback's program runs through the same `run_batched` (its sharding and chunking are
    the three-point method's, checked above on a failing problem), and compiling it
    twice more here would cost half a minute."""
    code = (
        _SETUP
        + """
    rows = slice(6, 26)  # after the collinear problem
    for name, kw in (("one", dict(devices=1)), ("sharded", dict(chunk_size=16))):
        ok, r, t = jp.solve_pnp_batch(obj[rows], img[rows], K, **kw)
        out.update({name + "_ok": ok, name + "_rvecs": r, name + "_tvecs": t})
    np.savez(os.environ["OUT"], **out)
    """
    )
    out = _run_child(code, tmp_path)
    _assert_same(out, "one", ["sharded"], ["ok", "rvecs", "tvecs"])
    assert np.all(out["one_ok"]) and out["one_ok"].shape == (20,)


# --------------------------------------------------------------------------- one device


@jax.jit
def _toy(shared, x, y):
    """A cheap batched function with a pytree output (row i depends on row i only)."""
    return {"sum": x.sum(axis=1) * shared, "pair": (y * 2, jnp.argmax(x, axis=1))}


@pytest.mark.parametrize("chunk_size", [None, 1, 3, 7, 100])
def test_run_batched_chunks_equal_one_call(chunk_size):
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(23, 5)), rng.integers(0, 9, size=(23, 2, 2))
    ref = jax.tree.map(np.asarray, _toy(np.float64(2.0), x, y))
    out = jp.api.run_batched(_toy, (np.float64(2.0),), (x, y), chunk_size=chunk_size)
    assert jax.tree.structure(out) == jax.tree.structure(ref)
    for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(ref), strict=True):
        assert isinstance(a, np.ndarray) and a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)


def _padded_size(x):
    """Each row: the number of rows of the call it ran in (padding included), and x."""
    return jnp.full(x.shape[:1], x.shape[0]), x


@pytest.mark.parametrize(
    ("rows", "sizes"),
    [(1, {16}), (5, {16}), (16, {16}), (17, {32}), (50, {64}), (100, {64}), (150, {64, 32})],
)
def test_run_batched_pads_a_small_batch_to_its_bucket(rows, sizes):
    """With `min_tail`, a batch smaller than a chunk runs padded to the smallest
    `min_tail * 2^k` that holds it, as a last chunk does (one program for every batch
    size of a bucket: `solve_pnp_batch` compiles none for 7 problems after 5), and the
    padding rows are dropped."""
    x = np.arange(rows, dtype=np.float64)
    size, out = jp.api.run_batched(_padded_size, (), (x,), chunk_size=64, min_tail=16)
    assert set(size.tolist()) == sizes
    np.testing.assert_array_equal(out, x)
    # without `min_tail`: the batch as it is, chunks padded to the chunk size
    size, _ = jp.api.run_batched(_padded_size, (), (x,), chunk_size=64)
    assert set(size.tolist()) == ({rows} if rows <= 64 else {64})


def test_run_batched_static_arguments():
    def scaled(x, factor, *, offset):
        return x * factor + offset

    scaled_jit = jax.jit(scaled, static_argnums=1, static_argnames="offset")
    x = np.arange(10.0)
    trailing = jp.api.run_batched(
        lambda x, f, offset=0.0: scaled_jit(x, f, offset=offset), (), (x,), static=(3.0,)
    )
    np.testing.assert_array_equal(trailing, 3 * x)
    keywords = jp.api.run_batched(
        scaled_jit, (), (x,), static={"factor": 2.0, "offset": 1.0}, chunk_size=4
    )
    np.testing.assert_array_equal(keywords, 2 * x + 1)


def test_run_batched_rejects_bad_arguments():
    x = np.zeros((4, 2))
    for chunk_size in (0, -1, 1.5, True, "8"):
        with pytest.raises(ValueError, match="chunk_size"):
            jp.api.run_batched(_toy, (1.0,), (x, x), chunk_size=chunk_size)
    for devices in (0, -2, len(jax.devices()) + 1, "cpu", [], [1], 2.0):
        with pytest.raises(ValueError, match="devices"):
            jp.api.run_batched(_toy, (1.0,), (x, x), devices=devices)
    with pytest.raises(ValueError, match="batch"):
        jp.api.run_batched(_toy, (1.0,), (x, np.zeros((5, 2))))
    with pytest.raises(ValueError, match="batch"):
        jp.api.run_batched(_toy, (1.0,), (np.zeros((0, 2)), np.zeros((0, 2))))


def test_batch_devices_and_mesh():
    devices = jax.devices()
    assert jp.api.batch_devices() == tuple(devices)
    assert jp.api.batch_devices(1) == (devices[0],)
    assert jp.api.batch_devices(devices[0]) == (devices[0],)
    assert jp.api.batch_devices(list(devices)) == tuple(devices)
    with pytest.raises(ValueError, match="repeat"):
        jp.api.batch_devices([devices[0], devices[0]])
    mesh = jp.api.batch_mesh()
    assert mesh.axis_names == ("batch",) and mesh.devices.size == len(devices)


def test_pad_rows_repeats_the_last_problem():
    x = np.arange(6.0).reshape(3, 2)
    np.testing.assert_array_equal(_pad_rows(x, 5), np.vstack([x, x[-1:], x[-1:]]))
    assert _pad_rows(x, 3) is x


def test_argument_order():
    # (camera, model, image, mask) from shared + batched.
    assert _argument_order(False, False) == (0, 1, 2, 3)
    assert _argument_order(True, False) == (1, 0, 2, 3)
    assert _argument_order(False, True) == (0, 1, 2, 3)
    assert _argument_order(True, True) == (0, 1, 2, 3)
