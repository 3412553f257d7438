r"""Recognition verification (the paper's Section 5): the mixed algorithm decides
which hypotheses of a matcher are right.

A hypothesis is a model from the database plus 2D-3D matches of its vertices. The
mixed algorithm (`jaxpose.solve`) recovers the pose of every hypothesis at once (one
batch, `jaxpose.solve_many`, of hypotheses padded to the same number of matches, with
masks), and an
absolute rule accepts or rejects each one. With `N` matches, image noise of standard
deviation $\sigma$ px per coordinate and a confidence $c$ (default 0.999):

1. **Eq. 8 error.** At the right pose, $N e^2 / \sigma^2$ follows a $\chi^2$ law with
   $2N - 6$ degrees of freedom (2N residuals, 6 pose parameters fitted), so
   $e < \sigma \sqrt{\chi^2_{c}(2N - 6) / N}$ holds with probability $c$ (the quantile
   by the Wilson-Hilferty approximation, slightly conservative at few degrees of
   freedom).
2. **Consensus.** Each match's residual $|r_i|^2 / \sigma^2$ is (at most) $\chi^2_2$:
   every one of the `N` is below $\sigma \sqrt{-2 \ln((1 - c) / N)}$ with probability
   about $c$ (Bonferroni). The fraction of matches within that radius, the consensus,
   must reach `min_consensus` (default 1: every match).

A hypothesis needs `N >= 4` matches (with three, any triangle fits exactly and nothing
can be verified); the test grows sharper with `N`. Wrong hypotheses (a wrong model,
shuffled matches, a few wrong matches) leave residuals far above the noise: their
error and consensus fail the rule. Accepted hypotheses are ranked by error, then the
rejected ones.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..api._programs import stored_jit
from ..api._solve import solve, solve_many
from ..geometry._pose import Pose, observations, transform
from ..geometry._validate import as_camera, as_points, no_type_check
from ..solvers._residuals import pixel_residuals
from ..solvers._status import Status
from ._polyhedron import Polyhedron

__all__ = [
    "Hypothesis",
    "Verdict",
    "Verification",
    "acceptance_thresholds",
    "verify",
    "verify_hypotheses",
]


# Levenberg-Marquardt's budget of triplets per hypothesis (`Options.nonlinear_budget`).
NONLINEAR_BUDGET = 32


def acceptance_thresholds(count, noise, confidence: float = 0.999):
    r"""The two pixel thresholds of the acceptance rule for `count` matches.

    **Arguments:**
    - `count`: number of matches `N` (scalar, may be traced; `N <= 3` gives 0).
    - `noise`: image noise $\sigma$ (px, per coordinate).
    - `confidence`: probability $c$ that a right hypothesis passes each test.

    **Returns:** `(error_threshold, residual_threshold)`: the bound on the Eq. 8 error
    $\sigma \sqrt{\chi^2_c(2N - 6) / N}$ and on each match's residual
    $\sigma \sqrt{-2 \ln((1 - c) / N)}$ (module docstring).
    """
    count = jnp.asarray(count)
    noise = jnp.asarray(noise)
    if not jnp.issubdtype(noise.dtype, jnp.inexact):
        noise = noise.astype(float)
    dtype = noise.dtype
    n = jnp.maximum(count.astype(dtype), 1)
    dof = jnp.maximum(2 * n - 6, 1)
    z = jax.scipy.special.ndtri(jnp.asarray(confidence, dtype))
    a = 2 / (9 * dof)
    quantile = dof * jnp.maximum(1 - a + z * jnp.sqrt(a), 0) ** 3
    error = noise * jnp.sqrt(quantile / n)
    residual = noise * jnp.sqrt(-2 * jnp.log((1 - jnp.asarray(confidence, dtype)) / n))
    enough = count > 3
    return jnp.where(enough, error, 0), jnp.where(enough, residual, 0)


class Verification(NamedTuple):
    """The verdict on one hypothesis (JAX arrays; batched under `vmap`).

    **Fields:**
    - `pose`: `Pose(R, t)`, the Eq. 8 optimum found by the mixed algorithm over the
      hypothesis's matches (model to world), also for a rejected hypothesis (the identity
      when the mixed algorithm found nothing at all).
    - `error`: its Eq. 8 error (px).
    - `error_threshold`, `residual_threshold`: the rule's bounds (px).
    - `inliers`: `(n,)` bool, matches whose residual is within `residual_threshold`.
    - `consensus`: the fraction of matches that are inliers.
    - `accepted`: both tests passed.
    - `status`: the mixed algorithm's status when accepted (`ACCEPTED_LINEAR`,
      `ACCEPTED_AFTER_NONLINEAR`), `REJECTED` when the rule failed,
      `TOO_FEW_POINTS` with fewer than 4 matches, else the mixed algorithm's failure.
    """

    pose: Pose
    error: Float[Array, ""]
    error_threshold: Float[Array, ""]
    residual_threshold: Float[Array, ""]
    inliers: Bool[Array, " n"]
    consensus: Float[Array, ""]
    accepted: Bool[Array, ""]
    status: Int[Array, ""]


def verify(
    camera: Float[Array, "3 4"],
    model: Float[Array, "n 3"],
    image: Float[Array, "n 2"],
    mask: Bool[Array, " n"] | None = None,
    *,
    noise: float | Float[Array, ""] = 1.0,
    confidence: float = 0.999,
    min_consensus: float = 1.0,
    max_triplets: int | None = 2000,
    nonlinear_budget: int | None = NONLINEAR_BUDGET,
) -> Verification:
    """Verify one hypothesis with the mixed algorithm (JAX-native, one problem).

    Pure and fixed-shape: pad hypotheses to a common `n` with `mask` and `jax.vmap` this
    to verify many at once (`verify_hypotheses` does it from numpy).

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C`, calibrated in the world frame.
    - `model`: `(n, 3)` the hypothesis's model vertices; `image`: `(n, 2)` their pixels.
    - `mask`: optional `(n,)` bool, which rows are real matches (the rest is padding).
    - `noise`: image noise (px, standard deviation per coordinate); may be traced.
    - `confidence`: probability that a right hypothesis passes each test.
    - `min_consensus`: the fraction of matches that must be inliers.
    - `max_triplets`, `nonlinear_budget`: as `jaxpose.solve`.

    **Returns:** a `Verification` (see the module docstring for the rule).
    """
    obs = observations(camera, model, image, mask)
    sol = solve(
        obs.camera,
        obs.model,
        obs.image,
        obs.mask,
        max_triplets=max_triplets,
        nonlinear_budget=nonlinear_budget,
        derivative=False,  # the verdict carries none
    )
    return _judge(obs, sol, noise, confidence, min_consensus)


def verdict(obs, pose: Pose, error, solved, status, noise, confidence: float, min_consensus: float):
    """The verification rule (module docstring), the one place it is written: for one
    hypothesis `obs` at `pose` of Eq. 8 `error`, `solved` whether the solver accepted
    it and `status` its status. Returns `(accepted, status, inliers, consensus,
    error_threshold, residual_threshold)`: not accepted with fewer than 4 matches
    (`TOO_FEW_POINTS`), where the solver failed (its status), or where the error or the
    consensus fails its bound (`REJECTED`)."""
    dtype = obs.camera.dtype
    count = jnp.sum(obs.mask)
    error_thr, residual_thr = acceptance_thresholds(count, jnp.asarray(noise, dtype), confidence)
    residuals = jnp.linalg.norm(pixel_residuals(transform(pose, obs.model), obs), axis=1)
    inliers = obs.mask & (residuals < residual_thr)
    consensus = jnp.sum(inliers) / jnp.maximum(count, 1)
    passed = (error < error_thr) & (consensus >= min_consensus)
    enough = count > 3
    accepted = solved & enough & passed
    status = jnp.select(
        [~enough, ~solved, ~passed], [Status.TOO_FEW_POINTS, status, Status.REJECTED], status
    ).astype(jnp.int32)
    return accepted, status, inliers, consensus.astype(dtype), error_thr, residual_thr


def _judge(obs, sol, noise, confidence: float, min_consensus: float) -> Verification:
    """`verdict` on the answer `sol` of the problem `obs` (one hypothesis)."""
    pose = jax.lax.stop_gradient(sol.pose)
    error = jax.lax.stop_gradient(sol.error)
    accepted, status, inliers, consensus, error_thr, residual_thr = verdict(
        obs, pose, error, sol.accepted, sol.status, noise, confidence, min_consensus
    )
    return Verification(
        pose=pose,
        error=error,
        error_threshold=error_thr,
        residual_threshold=residual_thr,
        inliers=inliers,
        consensus=consensus,
        accepted=accepted,
        status=status,
    )


# --------------------------------------------------------------------------- numpy side


# No run-time type check on construction: `verify_hypotheses` validates the fields (a
# `ValueError` naming the field).
@no_type_check
@dataclasses.dataclass(frozen=True)
class Hypothesis:
    """A recognition hypothesis: a model and matches of its vertices.

    **Fields:** `model` (`Polyhedron`); `vertices` `(k,)` indices into `model.vertices`;
    `image_points` `(k, 2)` the pixels matched to them; `label` (free text). Checked by
    `verify_hypotheses`, not on construction.
    """

    model: Polyhedron
    vertices: np.ndarray
    image_points: np.ndarray
    label: str = ""


@dataclasses.dataclass(frozen=True)
class Verdict:
    """The outcome for one `Hypothesis` (numpy).

    **Fields:** `hypothesis`; `index` (its position in the input list); `accepted`;
    `R`, `t` (model to world); `error` (Eq. 8, px); `error_threshold`,
    `residual_threshold` (px); `consensus`; `inliers` `(k,)` bool; `status` (`Status`).
    """

    hypothesis: Hypothesis
    index: int
    accepted: bool
    R: np.ndarray
    t: np.ndarray
    error: float
    error_threshold: float
    residual_threshold: float
    consensus: float
    inliers: np.ndarray
    status: Status


def _check_hypothesis(h, i) -> tuple[np.ndarray, np.ndarray]:
    name = f"hypotheses[{i}]"
    if not isinstance(h, Hypothesis):
        raise ValueError(f"{name} must be a Hypothesis, got {type(h).__name__}")
    if not isinstance(h.model, Polyhedron):
        raise ValueError(f"{name}.model must be a Polyhedron, got {type(h.model).__name__}")
    v = np.asarray(h.vertices)
    if v.ndim != 1 or not np.issubdtype(v.dtype, np.integer):
        raise ValueError(f"{name}.vertices must be a 1-D integer array, got {v.dtype} {v.shape}")
    count = len(h.model.vertices)
    if np.any(v < 0) or np.any(v >= count):
        raise ValueError(f"{name}.vertices must index the model's {count} vertices")
    if len(np.unique(v)) != len(v):
        raise ValueError(f"{name}.vertices must not repeat a vertex")
    img = as_points(h.image_points, f"{name}.image_points", 2, min_count=4)
    if len(img) != len(v):
        raise ValueError(
            f"{name}: {len(v)} vertices but {len(img)} image points; they must match one to one"
        )
    return np.asarray(h.model.vertices, np.float64)[v], img.astype(np.float64)


def verify_hypotheses(
    camera,
    hypotheses,
    *,
    noise: float = 1.0,
    confidence: float = 0.999,
    min_consensus: float = 1.0,
    max_triplets: int | None = 2000,
) -> list[Verdict]:
    """Verify a list of recognition hypotheses at once and rank them (float64).

    All hypotheses are padded to the largest number of matches and verified in one
    compiled call: the values of `jax.vmap(verify)`, solved batch-first (`solve_many`).

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C` (world frame).
    - `hypotheses`: a sequence of `Hypothesis` (each with at least 4 matches).
    - `noise`, `confidence`, `min_consensus`, `max_triplets`: see `verify`.

    **Returns:** one `Verdict` per hypothesis, accepted ones first by increasing error,
    then the rejected ones by increasing error (`Verdict.index` gives the input order).

    **Raises:** `ValueError` naming the argument for a bad camera, an empty list, a
    malformed hypothesis or bad options.
    """
    C = as_camera(camera, "camera")
    hypotheses = list(hypotheses)
    if not hypotheses:
        raise ValueError("hypotheses must hold at least one Hypothesis")
    for name, value, ok in (
        ("noise", noise, lambda x: math.isfinite(x) and x > 0),
        ("confidence", confidence, lambda x: 0 < x < 1),
        ("min_consensus", min_consensus, lambda x: 0 <= x <= 1),
    ):
        try:
            good = not isinstance(value, bool) and ok(float(value))
        except (TypeError, ValueError):
            good = False
        if not good:
            raise ValueError(f"{name} is out of range or not a number, got {value!r}")
    pairs = [_check_hypothesis(h, i) for i, h in enumerate(hypotheses)]
    H, n = len(pairs), max(len(m) for m, _ in pairs)
    model = np.zeros((H, n, 3))
    image = np.zeros((H, n, 2))
    mask = np.zeros((H, n), dtype=bool)
    for i, (m, x) in enumerate(pairs):
        model[i, : len(m)], image[i, : len(x)], mask[i, : len(m)] = m, x, True
    with jax.enable_x64(True):
        out = _verify_batch(
            jnp.asarray(C, jnp.float64),
            jnp.asarray(model),
            jnp.asarray(image),
            jnp.asarray(mask),
            jnp.asarray(noise, jnp.float64),
            float(confidence),
            float(min_consensus),
            max_triplets,
        )
        out = jax.tree.map(np.asarray, out)
    verdicts = [
        Verdict(
            hypothesis=h,
            index=i,
            accepted=bool(out.accepted[i]),
            R=out.pose.R[i],
            t=out.pose.t[i],
            error=float(out.error[i]),
            error_threshold=float(out.error_threshold[i]),
            residual_threshold=float(out.residual_threshold[i]),
            consensus=float(out.consensus[i]),
            inliers=out.inliers[i, : len(pairs[i][0])],
            status=Status(int(out.status[i])),
        )
        for i, h in enumerate(hypotheses)
    ]
    return sorted(verdicts, key=lambda v: (not v.accepted, v.error, v.index))


@stored_jit(static_argnames=("confidence", "min_consensus", "max_triplets"))
def _verify_batch(camera, model, image, mask, noise, confidence, min_consensus, max_triplets):
    """`jax.vmap(verify)`'s values, the hypotheses solved batch-first (`solve_many`:
    the fallback runs only for those that need it) and without derivatives (the
    verdict carries none)."""
    sol = solve_many(
        camera,
        model,
        image,
        mask,
        max_triplets=max_triplets,
        nonlinear_budget=NONLINEAR_BUDGET,
        derivative=False,
    )
    obs = jax.vmap(observations, in_axes=(None, 0, 0, 0))(camera, model, image, mask)
    judge = functools.partial(_judge, confidence=confidence, min_consensus=min_consensus)
    return jax.vmap(judge, in_axes=(0, 0, None))(obs, sol, noise)
