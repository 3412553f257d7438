r"""Offline refinement of a tracked sequence (issue #32): every frame's pose refined jointly,
in one compiled call, from the measurements each frame kept (`TrackedFrame.rows`) and a
constant-velocity motion prior.

**The cost.** Over the frames with a pose (`ok`), with `p_i = R_i c + t_i` the object's
centre `c` in frame `i` and `a_i = log(R_{i+1} R_i^T)` the rotation from frame `i` to
`i + 1` (a rotation vector, the paper's Appendix A):

    sum_i sum_k w_ik / s_ik^2 rho_ik(R_i, t_i)^2
      + sum_i |p_{i+1} - 2 p_i + p_{i-1}|^2 / sigma_t^2 + |a_i - a_{i-1}|^2 / sigma_r^2

The first term is each frame's own: the residuals `rho` (px) of its stored edge and point
rows (the planes of the small-movement linear method, `jaxpose.apps._track_solve`) with
the robust weights `w / s^2` its last solve gave them (Tukey's weight over its kind's
scale squared), so that without the prior each frame's minimum is the tracker's pose. The
second is a constant-velocity prior on the centre and on the orientation, over every
three consecutive frames with a pose (a lost frame breaks the chain). `sigma_t` is
`translation_sigma` times the median distance of the object, `sigma_r`
`rotation_sigma` (degrees): the acceleration per frame^2 the motion is expected to have,
per axis.

**The prior's sigmas from the track** (`motion_sigmas`, the default). Each sigma is
the spread of the tracked trajectory's own second differences: over the same triples of
frames, `sqrt(median |d|^2 / 2.366)` for `d` the second difference of the rotation
(`a_i - a_{i-1}`) and of the centre (over the median distance), 2.366 being the median
of a chi-square with 3 degrees of freedom (a Gaussian `d` of that spread per axis). The
tracker's noise is in those differences too, so the prior is never stiffer than the
motion: a fixed sigma fits one motion only. On `box.mp4` (moved by hand) the estimate is
about 0.06 degree per frame^2; on the rendered benchmark's turns of up to 20 degrees in
24 frames (whose true second differences reach 0.6-1.5 degrees) 0.3-0.9, where a fixed
0.05 pulled the trajectory off the turns (`docs/tracking.md`).

**The solve.** Gauss-Newton with Marquardt's damping (a step that does not lower the cost
is refused and the damping raised) on all frames' 6-vectors at once: each frame's
small motion `(dt_i, r_i)` turns about its centre `p_i` (Eq. 3), so that `p_i` moves by
`dt_i` exactly and the prior's Jacobian is constant (`[1, -2, 1]` on three frames; the
rotation's taken as the identity: exact to first order in the frame-to-frame rotation).
The normal equations are block-banded (each frame meets its two neighbours on either
side); grouped by pairs of frames they are block-tridiagonal with 12 x 12 blocks, and
solved by block elimination over the pairs (`jax.lax.scan`, each Schur complement
factored by Cholesky; LAPACK's compiled in a third of the time of the unrolled one of
`jaxpose.solvers._linalg` and ran twice as fast here): time and memory linear in the
number of frames. Marquardt's damping (at least `1e-6` of the diagonal) keeps every block
positive definite; a step whose factorisation fails is refused like one that does not
lower the cost.

**Fixed shapes.** Frames padded to `bucket_points(F)` and rows to `bucket_points(U)`
(`jaxpose.api._programs`), one stored program per pair of buckets.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import cho_solve

from ..api._programs import bucket_points, program
from ..geometry._rotation import matrix_to_rotvec, rotvec_to_matrix
from ..geometry._validate import no_type_check
from ._track import TrackedFrame
from ._track_solve import _float, _orthonormal, plane_rows

__all__ = ["RefinedTrack", "motion_sigmas", "refine_track"]


#: `motion_sigmas` without three consecutive frames with a pose (degrees per frame^2; a
#: fraction of the distance per frame^2).
_FALLBACK_ROTATION, _FALLBACK_TRANSLATION = 0.05, 2e-4


class RefinedTrack(NamedTuple):
    """`refine_track`'s result.

    **Fields:**
    - `frames`: the frames, each with its refined pose and the RMS residual (px) of its
      stored rows there (lost frames unchanged).
    - `cost_before`, `cost_after`: the joint cost (module docstring) at the tracked and at
      the refined poses.
    - `iterations`: the Gauss-Newton steps taken (refused ones included).
    - `rotation_sigma`, `translation_sigma`: the prior's sigmas used (given, or
      `motion_sigmas` of the frames).
    """

    frames: list[TrackedFrame]
    cost_before: float
    cost_after: float
    iterations: int
    rotation_sigma: float = _FALLBACK_ROTATION
    translation_sigma: float = _FALLBACK_TRANSLATION


#: The median of a chi-square with 3 degrees of freedom: `|d|^2 / sigma^2` of a 3-vector
#: `d` with independent Gaussian components of standard deviation `sigma`.
_CHI2_3_MEDIAN = 2.365974

#: The sigmas `motion_sigmas` falls back on, and its least ones.
_FALLBACK = (_FALLBACK_ROTATION, _FALLBACK_TRANSLATION)
_LEAST = (1e-3, 1e-6)


def _used(frames: Sequence[TrackedFrame]) -> list[bool]:
    """Which frames take part: a pose (`ok`) with measurements kept (`rows`)."""
    return [f.ok and f.rows is not None and len(f.rows.point) > 0 for f in frames]


def _links(frames: Sequence[TrackedFrame], posed: list[bool]) -> list[int]:
    """The positions `i` whose frames `i - 1`, `i`, `i + 1` all take part (`posed`) and
    have consecutive numbers (the triples the prior links)."""
    return [
        i for i in range(1, len(frames) - 1)
        if posed[i - 1] and posed[i] and posed[i + 1]
        and frames[i].frame - frames[i - 1].frame == 1
        and frames[i + 1].frame - frames[i].frame == 1
    ]  # fmt: skip


def motion_sigmas(frames: Sequence[TrackedFrame], centre) -> tuple[float, float]:
    """The motion prior's sigmas `(rotation_sigma, translation_sigma)` that
    `refine_track` takes by default: the spread per axis of the tracked trajectory's
    second differences (module docstring), over the triples of consecutive frames with
    a pose; `(0.05, 2e-4)` without any, never below `(1e-3, 1e-6)`.

    **Arguments:** `frames` as `refine_track` takes them; `centre` `(3,)` the model
    point whose path is smoothed.
    """
    return _sigmas(frames, _links(frames, _used(frames)), np.asarray(centre, np.float64))


def _sigmas(frames: Sequence[TrackedFrame], links: list[int],
            centre: np.ndarray) -> tuple[float, float]:  # fmt: skip
    """`motion_sigmas` over the triples `links` (`_links`)."""
    import cv2

    if not links:
        return _FALLBACK
    rot, move, distance = [], [], []
    for i in links:
        a, b, c = frames[i - 1], frames[i], frames[i + 1]
        w0 = cv2.Rodrigues(b.R @ a.R.T)[0].ravel()
        w1 = cv2.Rodrigues(c.R @ b.R.T)[0].ravel()
        rot.append(float(np.sum((w1 - w0) ** 2)))
        p = [f.R @ centre + f.t for f in (a, b, c)]
        move.append(float(np.sum((p[2] - 2 * p[1] + p[0]) ** 2)))
        distance.append(float(np.linalg.norm(p[1])))
    rotation = math.degrees(math.sqrt(float(np.median(rot)) / _CHI2_3_MEDIAN))
    scale = max(float(np.median(distance)), 1e-12)
    translation = math.sqrt(float(np.median(move)) / _CHI2_3_MEDIAN) / scale
    return max(rotation, _LEAST[0]), max(translation, _LEAST[1])


def _data(R, t, model, planes, mask, omega, centre):
    """Each frame's normal equations `H (F, 6, 6)`, gradient `g (F, 6)` and cost `(F,)`
    of its rows (rotation about its centre), and `sum w r^2` with the Tukey weights."""
    p = jnp.einsum("fij,j->fi", R, centre) + t
    r, J, _ = jax.vmap(plane_rows)(R, t, model, planes, mask, p)
    w = omega[:, :, None] * mask
    Jw = J * w[..., None]
    H = jnp.einsum("fuki,fukj->fij", Jw, J)
    g = jnp.einsum("fuki,fuk->fi", Jw, r)
    return H, g, jnp.sum(w * r * r, axis=(1, 2)), r


def _acceleration(R, t, centre, link):
    """The prior's residuals `(F, 6)` (centre, rotation) at each frame, 0 off `link`."""
    p = jnp.einsum("fij,j->fi", R, centre) + t
    step_p = p[1:] - p[:-1]
    step_r = jax.vmap(matrix_to_rotvec)(jnp.einsum("fij,fkj->fik", R[1:], R[:-1]))
    acc = jnp.concatenate([step_p[1:] - step_p[:-1], step_r[1:] - step_r[:-1]], axis=1)
    zero = jnp.zeros((1, 6), acc.dtype)
    acc = jnp.concatenate([zero, acc, zero])
    return jnp.where(link[:, None], acc, 0)


def _block_tridiagonal_solve(D, B, b):
    """`x` of the symmetric positive definite block-tridiagonal system with diagonal
    blocks `D (K, m, m)`, blocks below the diagonal `B (K, m, m)` (`B[k]` at `(k, k-1)`;
    `B[0]` unused) and right-hand side `b (K, m)`: block elimination (`jax.lax.scan`),
    each Schur complement `S_k = D_k - B_k S_{k-1}^-1 B_k^T` factored once (Cholesky)."""

    def forward(carry, inputs):
        L_prev, y_prev = carry
        Dk, Bk, bk = inputs
        Z = cho_solve((L_prev, True), Bk.T)
        z = cho_solve((L_prev, True), y_prev)
        S = Dk - Bk @ Z
        L = jnp.linalg.cholesky(0.5 * (S + S.T))
        y = bk - Bk @ z
        return (L, y), (L, y)

    m = D.shape[-1]
    start = (jnp.eye(m, dtype=D.dtype), jnp.zeros(m, D.dtype))
    B = B.at[0].set(0)
    _, (L, y) = jax.lax.scan(forward, start, (D, B, b))
    x_last = cho_solve((L[-1], True), y[-1])

    def backward(x_next, inputs):
        Lk, yk, B_next = inputs
        x = cho_solve((Lk, True), yk - B_next.T @ x_next)
        return x, x

    _, xs = jax.lax.scan(backward, x_last, (L[:-1], y[:-1], B[1:]), reverse=True)
    return jnp.concatenate([xs, x_last[None]])


def _refine(R, t, model, planes, mask, omega, active, link, centre, inv_sigma, iterations):
    """The joint refinement (module docstring), padded shapes. Returns `(R, t, cost
    before, cost after, steps)`."""
    dtype = t.dtype
    F = R.shape[0]
    W = jnp.concatenate([jnp.full(3, inv_sigma[0] ** 2), jnp.full(3, inv_sigma[1] ** 2)])
    on = link.astype(dtype)
    before, after = (
        jnp.concatenate([on[1:], jnp.zeros(1, dtype)]),
        jnp.concatenate([jnp.zeros(1, dtype), on[:-1]]),
    )
    # the prior's (constant) normal matrix: coefficients times diag(W) per frame pair
    c0 = before + 4 * on + after  # (i, i)
    c1 = -2 * on - 2 * after  # (i, i-1)
    c2 = after  # (i, i-2)
    eye6 = jnp.eye(6, dtype=dtype)

    def cost(R, t):
        _, _, data, _ = _data(R, t, model, planes, mask, omega, centre)
        acc = _acceleration(R, t, centre, link)
        return jnp.sum(jnp.where(active, data, 0)) + jnp.sum(acc * acc * W[None, :])

    def system(R, t, mu):
        H, g, _, _ = _data(R, t, model, planes, mask, omega, centre)
        acc = _acceleration(R, t, centre, link)
        Wacc = acc * W[None, :]
        nxt = jnp.concatenate([Wacc[1:], jnp.zeros((1, 6), dtype)])
        prv = jnp.concatenate([jnp.zeros((1, 6), dtype), Wacc[:-1]])
        g = g + nxt - 2 * Wacc + prv
        A = H + c0[:, None, None] * jnp.diag(W)[None]
        # Marquardt's damping on the diagonal; a frame without a pose is held.
        A = A + mu * jnp.diagonal(A, axis1=1, axis2=2)[:, :, None] * eye6[None]
        A = jnp.where(active[:, None, None], A, eye6[None])
        g = jnp.where(active[:, None], g, 0)
        O1 = c1[:, None, None] * jnp.diag(W)[None]
        O2 = c2[:, None, None] * jnp.diag(W)[None]
        K = F // 2
        A2, O1_2, O2_2 = (a.reshape(K, 2, 6, 6) for a in (A, O1, O2))
        zero = jnp.zeros((K, 6, 6), dtype)
        D = jnp.concatenate(
            [
                jnp.concatenate([A2[:, 0], jnp.swapaxes(O1_2[:, 1], 1, 2)], axis=2),
                jnp.concatenate([O1_2[:, 1], A2[:, 1]], axis=2),
            ],
            axis=1,
        )
        Bk = jnp.concatenate(
            [
                jnp.concatenate([O2_2[:, 0], O1_2[:, 0]], axis=2),
                jnp.concatenate([zero, O2_2[:, 1]], axis=2),
            ],
            axis=1,
        )
        x = _block_tridiagonal_solve(D, Bk, -g.reshape(K, 12))
        return x.reshape(F, 6)

    def update(R, t, x):
        p = jnp.einsum("fij,j->fi", R, centre) + t
        dR = jax.vmap(rotvec_to_matrix)(x[:, 3:])
        R1 = jnp.einsum("fij,fjk->fik", dR, R)
        t1 = jnp.einsum("fij,fj->fi", dR, t - p) + p + x[:, :3]
        return R1, t1

    def body(_, state):
        R, t, mu, value = state
        x = system(R, t, mu)
        finite = jnp.all(jnp.isfinite(x))  # (a factor that failed: NaN, the step refused)
        R1, t1 = update(R, t, jnp.where(finite, x, 0))
        value1 = cost(R1, t1)
        better = finite & jnp.isfinite(value1) & (value1 < value)
        return (
            jnp.where(better, R1, R),
            jnp.where(better, t1, t),
            jnp.clip(jnp.where(better, mu * 0.1, mu * 10), 1e-6, 1e6),
            jnp.where(better, value1, value),
        )

    start = cost(R, t)
    mu0 = jnp.asarray(1e-4, dtype)
    R, t, _, end = jax.lax.fori_loop(0, iterations, body, (R, t, mu0, start))
    _, _, _, r = _data(R, t, model, planes, mask, omega, centre)
    return R, t, start, end, r


_PROGRAM = program(_refine)


def _check_positive(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return float(value)


@no_type_check  # (its arguments checked by itself, with a ValueError naming each)
def refine_track(
    frames: Sequence[TrackedFrame],
    *,
    rotation_sigma: float | None = None,
    translation_sigma: float | None = None,
    iterations: int = 8,
    centre=None,
) -> RefinedTrack:
    """Refine a tracked sequence jointly (module docstring), in one compiled call.

    **Arguments:**
    - `frames`: the tracker's results in order (`jaxpose.apps.track`), each frame with a
      pose keeping its measurements (`TrackedFrame.rows`).
    - `rotation_sigma`: the expected change of the rotation per frame between
      consecutive frames (degrees per frame^2, per axis): smaller smooths more. None:
      from the track itself (`motion_sigmas`: the spread of its own second
      differences).
    - `translation_sigma`: the same for the object's centre, as a fraction of its
      distance to the camera (per frame^2); None: from the track.
    - `iterations`: Gauss-Newton steps.
    - `centre`: the model point whose path the prior smooths (default: the centroid of
      the measured model points).

    **Returns:** a `RefinedTrack`. Frames without a pose (`ok` False) or without rows
    are left as they are and break the prior's chain, as do gaps in the frame numbers.

    **Raises:** `ValueError` naming the argument.
    """
    frames = list(frames) if not isinstance(frames, list) else frames
    if not all(isinstance(f, TrackedFrame) for f in frames):
        raise ValueError("frames must be a sequence of TrackedFrame (from track)")
    if rotation_sigma is not None:
        rotation_sigma = _check_positive("rotation_sigma", rotation_sigma)
    if translation_sigma is not None:
        translation_sigma = _check_positive("translation_sigma", translation_sigma)
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ValueError(f"iterations must be an int >= 1, got {iterations!r}")
    used = _used(frames)
    for f, u in zip(frames, used):
        if u and not all(np.all(np.isfinite(np.asarray(a, np.float64))) for a in (f.R, f.t)):
            raise ValueError(f"frames: frame {f.frame} has a pose that is not finite")
    if centre is not None:
        centre = np.asarray(centre, np.float64)
        if centre.shape != (3,) or not np.all(np.isfinite(centre)):
            raise ValueError(f"centre must be None or 3 finite numbers, got {centre!r}")
    elif any(used):
        stacked = np.vstack([f.rows.model for f, u in zip(frames, used) if u])  # type: ignore[union-attr]
        centre = stacked.mean(axis=0)
    if sum(used) < 3:  # no three frames: nothing to smooth
        return RefinedTrack(list(frames), 0.0, 0.0, 0, rotation_sigma or _FALLBACK[0],
                            translation_sigma or _FALLBACK[1])  # fmt: skip
    assert centre is not None
    links = _links(frames, used)
    if rotation_sigma is None or translation_sigma is None:
        found = _sigmas(frames, links, np.asarray(centre, np.float64))
        rotation_sigma = found[0] if rotation_sigma is None else rotation_sigma
        translation_sigma = found[1] if translation_sigma is None else translation_sigma
    F = bucket_points(max(len(frames), 2))
    U = bucket_points(max(len(f.rows.point) for f, u in zip(frames, used) if u))  # type: ignore[union-attr]
    f = _float()
    R = np.tile(np.eye(3, dtype=f), (F, 1, 1))
    t = np.tile(np.array([0.0, 0.0, 1.0], f), (F, 1))
    model = np.zeros((F, U, 3), f)
    planes = np.zeros((F, U, 2, 3), f)
    mask = np.zeros((F, U, 2), bool)
    omega = np.zeros((F, U), f)
    active = np.zeros(F, bool)
    for i, (frame, u) in enumerate(zip(frames, used)):
        if not u:
            continue
        rows = frame.rows
        assert rows is not None
        n = len(rows.point)
        R[i], t[i], active[i] = frame.R, frame.t, True
        model[i, :n], planes[i, :n], mask[i, :n] = rows.model, rows.planes, rows.mask
        omega[i, :n] = rows.weights / np.maximum(rows.scales, 1e-12) ** 2
    link = np.zeros(F, bool)
    link[links] = True
    distance = np.median(np.linalg.norm(R[active] @ centre + t[active], axis=1))
    inv_sigma = np.array(
        [1 / (translation_sigma * max(distance, 1e-12)), 1 / math.radians(rotation_sigma)], f
    )
    out = _PROGRAM(R, t, model, planes, mask, omega, active, link, np.asarray(centre, f),
                   inv_sigma, np.int32(iterations))  # fmt: skip
    R1, t1, before, after, r = (np.asarray(a, np.float64) for a in out)
    refined = []
    for i, (frame, u) in enumerate(zip(frames, used)):
        if not u or not (np.all(np.isfinite(R1[i])) and np.all(np.isfinite(t1[i]))):
            refined.append(frame)
            continue
        rows = frame.rows
        assert rows is not None
        n = len(rows.point)
        w = rows.weights[:, None] * rows.mask
        rms = float(np.sqrt((w * r[i, :n] ** 2).sum() / max(w.sum(), 1e-300)))
        refined.append(frame._replace(R=_orthonormal(R1[i]), t=t1[i].copy(), rms=rms))
    return RefinedTrack(refined, float(before), float(after), iterations, rotation_sigma,
                        translation_sigma)  # fmt: skip
