"""A plain `jax.grad` (`jax.jacrev`, `jax.jacfwd`, `jax.jvp`) of `jaxpose.solve` runs a
stored program (`jaxpose.api._stored._stored_derivative`): the same derivative as the
traced path's, and a new process loads it instead of tracing the pipeline.

Every problem here is of the 16-point bucket, float64: one stored derivative program
and one traced reference (on the bucket's padded shapes, with a mask; the first rung's,
which accepts every problem here) for the file."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.api import _programs
from jaxpose.api import _solve as solve_module
from jaxpose.api._stored import _derivative_program
from jaxpose.strategy import escalation, split_values

SIZE = 16


def _outputs(C, M, x, mask=None):
    """Every differentiable output of `solve`: `R` (9), `t`, `error`, `pose_error`."""
    sol = jp.solve(C, M, x, mask)
    return jnp.concatenate([sol.pose.R.ravel(), sol.pose.t, sol.error[None], sol.pose_error[None]])


def _loss(C, M, x, mask=None):
    return _outputs(C, M, x, mask) @ np.linspace(1.0, -1.0, 14)


def _first_rung_outputs(C, M, x, mask=None):
    """`_outputs` of the first rung of the escalation alone (`fallback=False`): the
    default's on every problem the first rung accepts (the later rungs never run there),
    as on every problem of this file (`_reference` checks it), for a third of the
    compilation of the whole ladder."""
    sol = jp.solve(C, M, x, mask, fallback=False)
    out = jnp.concatenate([sol.pose.R.ravel(), sol.pose.t, sol.error[None], sol.pose_error[None]])
    return out, sol.accepted


# The traced path (`jax.jit` around the derivative), on the bucket's padded shapes.
_traced = jax.jit(jax.jacrev(_first_rung_outputs, argnums=(0, 1, 2), has_aux=True))


def _reference(C, M, x, mask=None):
    """The traced path's Jacobians of `_outputs`, `(14, 3, 4)`, `(14, n, 3)`,
    `(14, n, 2)`: the points padded to `SIZE` as the stored programs pad them
    (repeating the first, masked out), cut back."""
    n = len(M)
    mask = np.ones(n, bool) if mask is None else mask
    pad = SIZE - n
    Mp = np.concatenate([M, np.repeat(M[:1], pad, 0)])
    xp = np.concatenate([x, np.repeat(x[:1], pad, 0)])
    maskp = np.concatenate([mask, np.zeros(pad, bool)])
    (jC, jM, jx), accepted = _traced(C, Mp, xp, maskp)
    assert bool(accepted) or not np.all(np.isfinite(x))  # (else the ladder goes on)
    return np.asarray(jC), np.asarray(jM)[:, :n], np.asarray(jx)[:, :n]


def _close(a, b, rows=slice(None)):
    """`a` and `b` equal to 1e-10 of their scale (in their first axis' `rows`)."""
    a, b = np.asarray(a)[rows], np.asarray(b)[rows]
    assert a.shape == b.shape and np.all(np.isfinite(a))
    assert np.max(np.abs(a - b)) <= 1e-10 * max(1.0, np.max(np.abs(b)))


def _problem(seed: int, n: int = SIZE):
    b = jp.default_bench(seed=seed)
    return b.camera, b.model_points[:n], b.image_points[:n]


def _stored_program():
    return _programs.program(_derivative_program, escalation(split_values(jp.Options())[0])[0])


@pytest.mark.parametrize(
    "seed, n, masked",
    [(0, 16, False), (1, 16, False), (2, 12, False), (3, 16, True)],
)
def test_stored_gradient_is_the_traced_one(seed, n, masked):
    """The derivatives w.r.t. camera, model and image through the stored program
    (`jax.jacrev`, `jax.jacfwd`, `jax.grad`, `jax.value_and_grad`) equal the traced
    path's (1e-10 of their scale), also for `n` below the bucket's size and with a
    mask."""
    C, M, x = _problem(seed, n)
    mask = (np.arange(n) % 5 != 2) if masked else None
    calls = []
    stored = solve_module._stored_derivative
    with pytest.MonkeyPatch.context() as patch:  # under `jit`: the traced path
        patch.setattr(solve_module, "_stored_derivative", lambda *a: calls.append(a) or stored(*a))
        ref = _reference(C, M, x, mask)
    assert not calls
    for derivative in (jax.jacrev, jax.jacfwd):
        for got, r in zip(derivative(_outputs, argnums=(0, 1, 2))(C, M, x, mask), ref, strict=True):
            _close(got, r)
    assert _stored_program()._memo  # the stored program ran
    weights = np.linspace(1.0, -1.0, 14)
    value, grads = jax.value_and_grad(_loss, argnums=(0, 1, 2))(C, M, x, mask)
    assert np.isclose(float(value), float(_loss(C, M, x, mask)), rtol=1e-12, atol=1e-12)
    for got, r in zip(grads, ref, strict=True):
        _close(got, np.tensordot(weights, r, axes=1))
    if masked:  # the matches left out carry no derivative
        assert np.all(np.asarray(grads[2])[~mask] == 0)


def test_jvp_and_linearize_through_the_stored_program():
    """Forward mode (`jax.jvp`, `jax.linearize`) through the stored program: the
    Jacobian applied to the tangent."""
    C, M, x = _problem(0)
    ref = _reference(C, M, x)[2]
    dx = np.random.default_rng(0).normal(size=x.shape)
    _, tangent = jax.jvp(lambda i: _outputs(C, M, i), (x,), (dx,))
    _, linear = jax.linearize(lambda i: _outputs(C, M, i), x)
    expected = np.tensordot(ref, dx, axes=2)
    _close(tangent, expected)
    _close(linear(dx), expected)


def test_solve_many_through_the_stored_program():
    """`solve_many`'s plain derivative runs the same stored program (a batch of one
    here: `solve`'s shapes) and gives `solve`'s."""

    def many(image):
        sol = jp.solve_many(C, M[None], image)
        return jnp.concatenate([sol.pose.R.reshape(1, 9), sol.pose.t], axis=1)

    C, M, x = _problem(1)
    got = jax.jacrev(many)(x[None])
    assert got.shape == (1, 12, 1, SIZE, 2)
    _close(got[0, :, 0], _reference(C, M, x)[2], rows=slice(0, 12))


def test_no_nan_through_the_stored_program():
    """A non-finite match: a zero, finite derivative (the placeholder answer). A
    noise-free problem at the identity rotation: finite, the traced path's for the pose
    (the errors, zero there, have no derivative: a cone's tip, the rounding's direction)."""
    C, M, x = _problem(0)
    bad = x.copy()
    bad[3, 0] = np.nan
    for got in jax.jacrev(_outputs, argnums=(0, 1, 2))(C, M, bad):
        assert np.all(np.asarray(got) == 0)
    h = M @ C[:, :3].T + C[:, 3]  # the model in the world frame as it is: R = I, t = 0
    clean = h[:, :2] / h[:, 2:]
    got = jax.jacrev(_outputs, argnums=(0, 1, 2))(C, M, clean)
    for g, r in zip(got, _reference(C, M, clean), strict=True):
        assert np.all(np.isfinite(np.asarray(g)))
        _close(g, r, rows=slice(0, 12))


def test_only_a_plain_derivative_runs_the_stored_program():
    """`_differentiated` (which inputs run the stored derivative): a plain `jax.grad`,
    `jax.jacfwd`, `jax.jvp`, not one under the caller's `jit` or `vmap`, nor a second
    derivative (the traced path's there, as before)."""
    C, M, x = _problem(0)
    seen = []

    def probe(image):
        seen.append(solve_module._differentiated((C, M[None], image[None], None)))
        return (image**3).sum()

    jax.grad(probe)(x)
    jax.jacfwd(probe)(x)
    jax.jvp(probe, (x,), (x,))
    assert seen == [True, True, True]
    seen.clear()
    jax.jit(jax.grad(probe))(x)
    jax.vmap(jax.grad(probe))(np.stack([x, x]))
    jax.hessian(probe)(x)
    jax.grad(lambda i: jax.grad(probe)(i).sum())(x)
    probe(x)
    assert not any(seen) and len(seen) == 5


def test_a_new_process_loads_the_derivative_instead_of_tracing():
    """With the derivative program on disk, a new process's first `jax.grad(jp.solve)`
    traces no pipeline (`solve_problems` is never called) and compiles no program: it
    loads one, and gives this process's gradient."""
    C, M, x = _problem(0)
    here = np.asarray(jax.grad(lambda i: jp.solve(C, M, i).pose.t.sum())(x))
    script = textwrap.dedent(
        """
        import sys
        import jax
        jax.config.update("jax_enable_x64", True)
        import numpy as np
        import jaxpose as jp
        from jaxpose.api import _programs, _solve
        _programs._FINGERPRINT = sys.argv[1]  # this test's (sources edited meanwhile)
        traced = []
        original = _solve.solve_problems
        def counted(*args, **kwargs):
            traced.append(1)
            return original(*args, **kwargs)
        _solve.solve_problems = counted
        b = jp.default_bench(seed=0)
        C, M, x = b.camera, b.model_points, b.image_points
        g = jax.grad(lambda i: jp.solve(C, M, i).pose.t.sum())(x)
        compiled = sum(p.compiled for p in _programs._PROGRAMS.values())
        loaded = sum(p.loaded for p in _programs._PROGRAMS.values())
        print(len(traced), compiled, loaded)
        print(repr(np.asarray(g).tolist()))
        """
    )
    root = os.path.dirname(os.path.dirname(os.path.dirname(__file__)))
    out = subprocess.run(
        [sys.executable, "-c", script, _programs.fingerprint()],
        cwd=root,
        capture_output=True,
        text=True,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    counts, grad = out.stdout.strip().splitlines()
    assert counts.split() == ["0", "0", "1"]
    np.testing.assert_allclose(np.array(eval(grad)), here, rtol=0, atol=1e-13)
