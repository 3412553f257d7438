"""Accuracy of jaxpose beside OpenCV and PoseLib: the standard synthetic PnP protocol and
OpenCV's chessboard images.

**Synthetic protocol** (the RPnP / OPnP / MLPnP toolboxes'): `jaxpose.random_scene` with
`f = 800`, OpenCV's convention (world = camera frame, `C = K [I | 0]`) and camera-frame
points uniform in `[-2,2]x[-2,2]x[4,8]` ("ordinary"), `[1,2]x[1,2]x[4,8]`
("quasi_singular") or on a plane `[-2,2]^2` tilted by up to 30 degrees at depth 4-8
("planar"); Gaussian pixel noise `sigma`. Two sweeps per kind: `sigma` in
{0.5, 1, 2, 3, 4, 5} px at `n = 10`, and `n` in {4, 6, 10, 20, 50, 100, 200} at
`sigma = 2` px. Every method solves the same seeded instances. Errors, in the camera frame
(`x_cam = R X + t`): rotation error = the largest angle between matching axes (columns) of
`R_true` and `R_est` (degrees); translation error = `|t_est - t_true| / |t_true|` (%).
Medians and means over the trials of each cell.

Methods: jaxpose's four (`jaxpose.solve_pnp_batch`, float64, every trial of a cell in
fixed-size chunks, so one compilation per `(n, method)`; above `C(n, 3) = 2000` triplets
a fixed sample of 2000), OpenCV's `SOLVEPNP_EPNP`, `SOLVEPNP_SQPNP`, `SOLVEPNP_ITERATIVE`
and `SOLVEPNP_IPPE` (planar scenes only), and PoseLib's `estimate_absolute_pose` with a
10^4 px inlier threshold (every match an inlier) and a least-squares (`TRIVIAL` loss)
refinement.

**The ML optimum** of each trial, the minimum of Eq. 8 (RMS reprojection error): the best
of `cv2.solvePnPRefineLM` (float64, up to 200 iterations) started from SQPnP, from EPnP and
from the true pose. A method "is at the optimum" on a trial when its RMS reprojection
error is within `1e-6` px of the reference's (absolute; the stricter `1e-9` relative
criterion is counted too). Trials where jaxpose's mixed method misses it are kept in the
JSON as reproducers.

**Real images:** OpenCV's chessboard set (`tests/data/chessboard/`): corners by
`cv2.findChessboardCorners` and `cv2.cornerSubPix`, intrinsics and distortion from
`left_intrinsics.yml`; per image, jaxpose's pose (`jaxpose.solve_pnp`, mixed) against
OpenCV's reference pose (the calibration's own extrinsics, in the same file) and against
`cv2.solvePnP`, with the reprojection errors side by side.

    python benchmarks/accuracy.py            # full: 500 trials per cell (see --help)
    python benchmarks/accuracy.py --quick    # ~50 trials per cell

Prints tables and writes `benchmarks/results/accuracy.json` (every figure, the machine,
the library versions) and one PNG per kind (`accuracy_<kind>.png`). `run(quick, out_dir)`
is the entry point for `benchmarks/run.py`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import cv2
import numpy as np
from jaxtyping import Bool, Float

import jaxpose as jp

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).resolve().parent / "results"
CHESSBOARD = ROOT / "tests" / "data" / "chessboard"

KINDS = ("ordinary", "quasi_singular", "planar")
SIGMAS = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0)
NS = (4, 6, 10, 20, 50, 100, 200)
SIGMA_SWEEP_N = 10
N_SWEEP_SIGMA = 2.0
FOCAL = 800.0
JAX_METHODS = tuple(jp.METHODS)  # ("mixed", "three_point", "linear", "nonlinear")
OPENCV_FLAGS = {
    "EPNP": cv2.SOLVEPNP_EPNP,
    "SQPNP": cv2.SOLVEPNP_SQPNP,
    "ITERATIVE": cv2.SOLVEPNP_ITERATIVE,
    "IPPE": cv2.SOLVEPNP_IPPE,
}
ML = "ML optimum"
ABS_TOL = 1e-6  # px: "at the optimum" when within this of the ML optimum's RMS error
REL_TOL = 1e-9  # the stricter relative criterion, reported beside it
LOCAL_MINIMUM = 1e-3  # px above the optimum: another stationary point or an unrefined answer
REFINE_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-15)
POSELIB_THRESHOLD = 1e4  # px: every match is an inlier, so the answer is least squares
MAX_REPRODUCERS = {"mixed": 25}  # per kind and jaxpose method (others: 3)


def jaxpose_name(method: str) -> str:
    return f"jaxpose {method}"


def method_names(kind: str, jax_methods: Sequence[str] = JAX_METHODS) -> list[str]:
    """The methods run on scenes of `kind`, in table order (IPPE on planar scenes only)."""
    cv = [f"cv2 {k}" for k in OPENCV_FLAGS if k != "IPPE" or kind == "planar"]
    return [jaxpose_name(m) for m in jax_methods] + cv + ["PoseLib"]


# --------------------------------------------------------------------------- schedule


@dataclasses.dataclass(frozen=True)
class Schedule:
    """How many trials each cell gets.

    `trials` per cell, capped at large `n` by `large_n` (`{n: cap}`): every method runs
    on the same instances of a cell. The three jaxpose ablations (the paper's
    three-point, linear and non-linear methods run from every triplet) run on the first
    `ablation[method][n]` of them (absent: all; `0`: not run), because at large `n` they
    cost seconds per problem (the non-linear one runs LM on all 2000 triplets)."""

    trials: int
    large_n: dict[int, int]
    ablation: dict[str, dict[int, int]]

    def cell_trials(self, n: int) -> int:
        return min(self.trials, self.large_n.get(n, self.trials))

    def method_trials(self, n: int, method: str) -> int:
        cell = self.cell_trials(n)
        return min(cell, self.ablation.get(method, {}).get(n, cell))


def default_schedule(quick: bool, trials: int | None = None) -> Schedule:
    """The schedule of `--quick` (about 50 trials per cell) or of the full run (500).

    Measured per-problem cost of `solve_pnp_batch` (float64, compiled, on the 2-core CPU
    this was developed on, shared with other work): mixed 0.006-0.01 s at n = 10,
    0.06-0.1 s at n = 20, 0.3-0.5 s at n = 50, 0.5-1.1 s at n = 100, 1-1.4 s at n = 200;
    non-linear 0.04-0.06 s at n = 10, 0.8 s at n = 20 and about 7 s at n = 50 (LM on every
    triplet). The caps keep the full run near 25 minutes of solving there; compiling the
    28 programs comes on top (minutes; JAX's persistent cache removes it on a rerun)."""
    if quick:
        base = 50 if trials is None else trials
        large_n = {20: 50, 50: 20, 100: 10, 200: 5}
        few = {50: 5, 100: 5, 200: 5}
        nonlinear = {n: 20 for n in (4, 6, 10)} | {20: 25, 50: 0, 100: 0, 200: 0}
    else:
        base = 500 if trials is None else trials
        large_n = {50: 160, 100: 60, 200: 30}
        few = {50: 60, 100: 20, 200: 10}
        nonlinear = {n: 150 for n in (4, 6, 10)} | {20: 100, 50: 0, 100: 0, 200: 0}
    return Schedule(
        trials=base,
        large_n=large_n,
        ablation={"three_point": few, "linear": few, "nonlinear": nonlinear},
    )


def chunk_size(n: int, method: str = "mixed") -> int:
    """Problems per `solve_pnp_batch` call at `n` matches (a fixed shape: one compilation
    per `(n, method)`; the last chunk is padded). Bounded by memory: the linear and LM
    steps hold about `triplets x n` rows per problem; the non-linear method runs LM on
    every triplet, so it gets half as many problems once that is large."""
    rows = len(jp.triplet_indices(n, 2000)) * n
    size = max(1, min(50, int(2e6 // rows)))
    return max(1, size // 2) if method == "nonlinear" and rows > 10_000 else size


# --------------------------------------------------------------------------- geometry


def rotvec_to_matrix(r: Float[np.ndarray, "B 3"]) -> Float[np.ndarray, "B 3 3"]:
    """Rodrigues' formula for a batch of rotation vectors (numpy, float64)."""
    r = np.asarray(r, np.float64).reshape(-1, 3)
    theta = np.linalg.norm(r, axis=1)
    safe = np.where(theta > 0, theta, 1.0)
    u = r / safe[:, None]
    X = np.zeros((len(r), 3, 3))
    X[:, 0, 1], X[:, 0, 2], X[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
    X = X - np.swapaxes(X, 1, 2)
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * X + (1 - c) * (X @ X)


def rotation_error_deg(
    R_true: Float[np.ndarray, "B 3 3"], R_est: Float[np.ndarray, "B 3 3"]
) -> Float[np.ndarray, " B"]:
    """The largest angle (degrees) between matching axes (columns) of the two rotations;
    `2 asin(|a - b| / 2)` for unit vectors, accurate at small angles (unlike `acos`)."""
    d = np.linalg.norm(np.asarray(R_true) - np.asarray(R_est), axis=-2)
    return np.degrees(np.max(2 * np.arcsin(np.clip(d / 2, 0, 1)), axis=-1))


def rotation_angle_deg(
    R_a: Float[np.ndarray, "B 3 3"], R_b: Float[np.ndarray, "B 3 3"]
) -> Float[np.ndarray, " B"]:
    """The angle (degrees) of the rotation `R_a^T R_b`, from `|R_a - R_b|_F`."""
    frob = np.linalg.norm(np.asarray(R_a) - np.asarray(R_b), axis=(-2, -1))
    return np.degrees(2 * np.arcsin(np.clip(frob / (2 * np.sqrt(2)), 0, 1)))


def translation_error_pct(
    t_true: Float[np.ndarray, "B 3"], t_est: Float[np.ndarray, "B 3"]
) -> Float[np.ndarray, " B"]:
    """`100 |t_est - t_true| / |t_true|`."""
    return 100 * np.linalg.norm(t_est - t_true, axis=-1) / np.linalg.norm(t_true, axis=-1)


def reprojection_rms(
    obj: Float[np.ndarray, "B n 3"],
    img: Float[np.ndarray, "B n 2"],
    K: Float[np.ndarray, "3 3"],
    R: Float[np.ndarray, "B 3 3"],
    t: Float[np.ndarray, "B 3"],
) -> Float[np.ndarray, " B"]:
    """Eq. 8 for a batch of poses (pinhole `K`, no distortion): the RMS over the matches of
    the pixel distance between projection and observation."""
    p = np.einsum("bij,bnj->bni", R, obj) + t[:, None, :]
    q = p @ K.T
    uv = q[..., :2] / q[..., 2:]
    return np.sqrt(np.mean(np.sum((uv - img) ** 2, axis=-1), axis=-1))


# --------------------------------------------------------------------------- instances


@dataclasses.dataclass(frozen=True)
class Cell:
    """The seeded trials of one cell: `obj (B, n, 3)`, `img (B, n, 2)`, shared `K`, true
    camera-frame pose `R (B, 3, 3)`, `t (B, 3)`."""

    kind: str
    n: int
    sigma: float
    seed: tuple[int, ...]
    obj: np.ndarray
    img: np.ndarray
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray


def make_cell(kind: str, n: int, sigma: float, trials: int, seed: int = 0) -> Cell:
    """`trials` instances of `jaxpose.random_scene` (OpenCV's convention, so the scene's
    model-to-world pose is the camera-frame pose). One generator per cell, seeded by
    `(seed, kind, n, sigma)`: a shorter run's trials are a prefix of a longer run's."""
    key = (seed, KINDS.index(kind), n, round(sigma * 1000))
    rng = np.random.default_rng(key)
    scenes = [
        jp.random_scene(rng, n, noise=sigma, kind=kind, focal=FOCAL, world_camera=False)
        for _ in range(trials)
    ]
    return Cell(
        kind=kind,
        n=n,
        sigma=float(sigma),
        seed=key,
        obj=np.stack([s.model_points for s in scenes]),
        img=np.stack([s.image_points for s in scenes]),
        K=scenes[0].camera[:, :3].copy(),
        R=np.stack([s.R for s in scenes]),
        t=np.stack([s.t for s in scenes]),
    )


# --------------------------------------------------------------------------- solvers


@dataclasses.dataclass
class Answers:
    """Poses returned by one method on the first `len(ok)` trials of a cell."""

    R: np.ndarray
    t: np.ndarray
    ok: np.ndarray
    seconds: float
    extra: dict = dataclasses.field(default_factory=dict)


def _empty(B: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.tile(np.eye(3), (B, 1, 1)), np.zeros((B, 3)), np.zeros(B, bool)


def solve_jaxpose(cell: Cell, method: str, trials: int, chunk: int | None = None) -> Answers:
    """`jaxpose.solve_pnp_batch` over the first `trials` trials, in padded chunks of
    `chunk` (default `chunk_size(n)`; every call has the same shapes: one compilation per
    `(n, method)`)."""
    chunk = chunk or chunk_size(cell.n, method)
    R, t, ok = _empty(trials)
    t0 = time.perf_counter()
    first = None
    for s in range(0, trials, chunk):
        idx = np.minimum(np.arange(s, s + chunk), trials - 1)  # pad with the last trial
        c0 = time.perf_counter()
        okb, rv, tv = jp.solve_pnp_batch(cell.obj[idx], cell.img[idx], cell.K, method=method)
        if first is None:
            first = time.perf_counter() - c0
        m = min(chunk, trials - s)
        R[s : s + m], t[s : s + m], ok[s : s + m] = rotvec_to_matrix(rv[:m]), tv[:m], okb[:m]
    seconds = time.perf_counter() - t0
    return Answers(R, t, ok, seconds, {"chunk": chunk, "first_call_s": first})


def solve_opencv(cell: Cell, flag: int, trials: int) -> Answers:
    """`cv2.solvePnP` with `flag`, one call per trial (an OpenCV error is a failure)."""
    R, t, ok = _empty(trials)
    t0 = time.perf_counter()
    for i in range(trials):
        try:
            good, rv, tv = cv2.solvePnP(cell.obj[i], cell.img[i], cell.K, None, flags=flag)
        except cv2.error:
            continue
        if good:
            R[i], t[i], ok[i] = cv2.Rodrigues(rv)[0], tv.ravel(), True
    return Answers(R, t, ok, time.perf_counter() - t0)


def poselib_camera(K: np.ndarray) -> dict:
    return {
        "model": "PINHOLE",
        "width": 640,
        "height": 480,
        "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
    }


def solve_poselib(cell: Cell, trials: int) -> Answers:
    """`poselib.estimate_absolute_pose`: LO-RANSAC (P3P samples) with a 10^4 px threshold,
    so every match is an inlier and the sample of lowest squared error wins, then a
    least-squares (`TRIVIAL` loss) Levenberg-Marquardt refinement on all matches."""
    import poselib

    camera = poselib_camera(cell.K)
    ransac = {"max_reproj_error": POSELIB_THRESHOLD}
    bundle = {"loss_type": "TRIVIAL"}
    R, t, ok = _empty(trials)
    t0 = time.perf_counter()
    for i in range(trials):
        pose, _ = poselib.estimate_absolute_pose(cell.img[i], cell.obj[i], camera, ransac, bundle)
        R[i], t[i], ok[i] = pose.R, pose.t, True
    return Answers(R, t, ok, time.perf_counter() - t0)


def ml_optimum(cell: Cell, trials: int) -> tuple[Answers, np.ndarray, list[str]]:
    """The reference: for each trial, the lowest Eq. 8 error of `cv2.solvePnPRefineLM`
    started from SQPnP, EPnP and the true pose. Returns the answers, their RMS errors
    and which start won."""
    R, t, ok = _empty(trials)
    err = np.full(trials, np.inf)
    won: list[str] = []
    t0 = time.perf_counter()
    for i in range(trials):
        obj, img = cell.obj[i], cell.img[i]
        starts = {"true": (cv2.Rodrigues(cell.R[i])[0], cell.t[i].reshape(3, 1).copy())}
        for name in ("SQPNP", "EPNP"):
            try:
                good, rv, tv = cv2.solvePnP(obj, img, cell.K, None, flags=OPENCV_FLAGS[name])
            except cv2.error:
                continue
            if good and np.isfinite(rv).all() and np.isfinite(tv).all():
                starts[name] = (rv, tv)
        best = "none"
        for name, (rv, tv) in starts.items():
            rv, tv = cv2.solvePnPRefineLM(obj, img, cell.K, None, rv, tv, criteria=REFINE_CRITERIA)
            Ri = cv2.Rodrigues(rv)[0]
            e = reprojection_rms(obj[None], img[None], cell.K, Ri[None], tv.reshape(1, 3))[0]
            if e < err[i]:
                err[i], R[i], t[i], ok[i], best = e, Ri, tv.ravel(), True, name
        won.append(best)
    return Answers(R, t, ok, time.perf_counter() - t0), err, won


# --------------------------------------------------------------------------- statistics


def _stats(x: np.ndarray) -> dict:
    if len(x) == 0:
        return {"median": None, "mean": None, "p90": None, "max": None}
    return {
        "median": float(np.median(x)),
        "mean": float(np.mean(x)),
        "p90": float(np.quantile(x, 0.9)),
        "max": float(np.max(x)),
    }


def summarise(
    cell: Cell, ans: Answers, ml_err: np.ndarray
) -> tuple[dict, Bool[np.ndarray, " B"], np.ndarray]:
    """Error statistics of one method on one cell, and where it missed the ML optimum.

    Failures (not `ok`, or non-finite) are left out of the error statistics, counted in
    `failed`, and count as not at the optimum."""
    B = len(ans.ok)
    R_true, t_true = cell.R[:B], cell.t[:B]
    finite = np.isfinite(ans.R).all(axis=(1, 2)) & np.isfinite(ans.t).all(axis=1)
    valid = ans.ok & finite
    rot = rotation_error_deg(R_true, ans.R)
    trans = translation_error_pct(t_true, ans.t)
    with np.errstate(all="ignore"):
        rms = reprojection_rms(cell.obj[:B], cell.img[:B], cell.K, ans.R, ans.t)
    gap = np.where(valid, rms - ml_err[:B], np.inf)
    at_abs = gap <= ABS_TOL
    at_rel = gap <= REL_TOL * ml_err[:B]
    out = {
        "trials": int(B),
        "failed": int(B - valid.sum()),
        "rotation_deg": _stats(rot[valid]),
        "translation_pct": _stats(trans[valid]),
        "reprojection_px": _stats(rms[valid]),
        "at_optimum_abs": int(at_abs.sum()),
        "at_optimum_rel": int(at_rel.sum()),
        "above_optimum": int((valid & ~at_abs).sum()),
        "local_minima": int((valid & (gap > LOCAL_MINIMUM)).sum()),
        "max_gap_px": float(np.max(gap[valid])) if valid.any() else None,
        "below_reference": int((valid & (gap < -ABS_TOL)).sum()),
        "seconds": ans.seconds,
    } | ans.extra
    return out, ~at_abs, gap


def reproducer(cell: Cell, i: int, name: str, ans: Answers, ml: Answers, ml_err, gap) -> dict:
    """A trial a method got wrong, with everything needed to run it again."""
    return {
        "method": name,
        "kind": cell.kind,
        "n": cell.n,
        "sigma": cell.sigma,
        "cell_seed": list(cell.seed),
        "trial": int(i),
        "ok": bool(ans.ok[i]),
        "rms_px": float(ml_err[i] + gap[i]) if np.isfinite(gap[i]) else None,
        "ml_rms_px": float(ml_err[i]),
        "gap_px": float(gap[i]) if np.isfinite(gap[i]) else None,
        "rotation_from_ml_deg": float(rotation_angle_deg(ans.R[i : i + 1], ml.R[i : i + 1])[0]),
        "K": cell.K.tolist(),
        "object_points": cell.obj[i].tolist(),
        "image_points": cell.img[i].tolist(),
        "R_true": cell.R[i].tolist(),
        "t_true": cell.t[i].tolist(),
        "R_ml": ml.R[i].tolist(),
        "t_ml": ml.t[i].tolist(),
        "R_method": ans.R[i].tolist(),
        "t_method": ans.t[i].tolist(),
    }


def diagnose(rep: dict, *, max_steps: int = 500) -> dict:
    """Why jaxpose's mixed method missed the ML optimum on a reproducer.

    Runs `jaxpose.solve` (mixed, float64): the status of its answer and its error. For
    `n <= 10` also `jaxpose.mixed` (the per-triplet outcome, with `solve`'s non-linear
    budget) and, from every three-point root of every triplet, Levenberg-Marquardt with a
    generous `max_steps`: which roots lead to the ML optimum (within 1e-6 px), and their
    rank by Eq. 8 error within their triplet (the mixed method refines rank 0 first)."""
    import jax
    import jax.numpy as jnp

    K = np.asarray(rep["K"])
    C = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    ml = rep["ml_rms_px"]
    with jax.enable_x64(True):
        args = tuple(
            jnp.asarray(a, jnp.float64) for a in (C, rep["object_points"], rep["image_points"])
        )
        sol = jax.jit(jp.solve)(*args)
        status = jp.Status(int(sol.status))
        out = {
            "accepted": bool(sol.accepted),
            "status": status.name,
            "message": status.message,
            "error_px": float(sol.error),
            "error_minus_ml_px": float(sol.error) - ml,
            "triplet": int(sol.triplet),
        }
        if rep["n"] > 10:
            return out

        def per_triplet(C, model, image):
            obs = jp.observations(C, model, image)
            res = jp.mixed(obs, nonlinear_budget=32)
            ini = res.initial
            R = jnp.concatenate([ini.pose.R[:, None], ini.alt_pose.R], axis=1)
            t = jnp.concatenate([ini.pose.t[:, None], ini.alt_pose.t], axis=1)

            def refine(R, t):
                return jp.nonlinear(obs, jp.Pose(R, t), max_steps=max_steps)

            refined = jax.vmap(jax.vmap(refine))(R, t)
            root_error = jnp.concatenate([ini.error[:, None], ini.alt_error], axis=1)
            return res, root_error, refined.error, refined.pose.R

        res, root_error, lm_error, lm_R = jax.jit(per_triplet)(*args)
        big = np.finfo(np.float64).max / 2
        roots = np.asarray(root_error) < big
        reach = roots & (np.asarray(lm_error) <= ml + ABS_TOL)
        ml_R = np.asarray(rep["R_ml"])
        triplets = []
        for k in range(len(res.error)):
            triplets.append(
                {
                    "initial_status": jp.Status(int(res.initial.status[k])).name,
                    "status": jp.Status(int(res.status[k])).name,
                    "error_px": float(res.error[k]),
                    "root": int(res.root[k]),
                    "root_p3p_error_px": [float(e) for e in np.asarray(root_error[k])[roots[k]]],
                    "root_lm_error_px": [float(e) for e in np.asarray(lm_error[k])[roots[k]]],
                    "root_lm_deg_from_ml": [
                        float(rotation_angle_deg(np.asarray(R)[None], ml_R[None])[0])
                        for R in np.asarray(lm_R[k])[roots[k]]
                    ],
                }
            )
        out |= {
            "lm_max_steps": max_steps,
            "roots": int(roots.sum()),
            "roots_reaching_ml": int(reach.sum()),
            "best_roots_reaching_ml": int(reach[:, 0].sum()),
            "triplets": triplets,
        }
        return out


def run_cell(
    cell: Cell,
    schedule: Schedule,
    jax_methods: Sequence[str],
    reproducers: list,
    progress=None,
    chunk: int | None = None,
) -> dict:
    """Every method on one cell: statistics per method, the ML optimum's own errors."""
    B = len(cell.obj)
    ml, ml_err, won = ml_optimum(cell, B)
    ml_stats, _, _ = summarise(cell, ml, ml_err)
    ml_stats["start_won"] = {k: won.count(k) for k in sorted(set(won))}
    rows: dict[str, dict] = {ML: ml_stats}
    for method in jax_methods:
        trials = schedule.method_trials(cell.n, method)
        name = jaxpose_name(method)
        if trials == 0:
            rows[name] = {"trials": 0, "skipped": "cost (see the schedule)"}
            continue
        if progress is not None:
            progress(f"{cell.kind} n={cell.n} sigma={cell.sigma:g}: {name} x {trials}")
        ans = solve_jaxpose(cell, method, trials, chunk)
        rows[name], missed, gap = summarise(cell, ans, ml_err)
        kept = [r for r in reproducers if r["method"] == name and r["kind"] == cell.kind]
        room = MAX_REPRODUCERS.get(method, 3) - len(kept)
        for i in np.flatnonzero(missed)[: max(0, room)]:
            reproducers.append(reproducer(cell, i, name, ans, ml, ml_err, gap))
    if progress is not None:
        progress(f"{cell.kind} n={cell.n} sigma={cell.sigma:g}: OpenCV, PoseLib x {B}")
    for key, flag in OPENCV_FLAGS.items():
        if key == "IPPE" and cell.kind != "planar":
            continue
        rows[f"cv2 {key}"], _, _ = summarise(cell, solve_opencv(cell, flag, B), ml_err)
    rows["PoseLib"], _, _ = summarise(cell, solve_poselib(cell, B), ml_err)
    return {
        "kind": cell.kind,
        "n": cell.n,
        "sigma": cell.sigma,
        "trials": B,
        "seed": list(cell.seed),
        "methods": rows,
    }


# --------------------------------------------------------------------------- chessboard


def chessboard(data: Path = CHESSBOARD, method: str = "mixed") -> dict:
    """jaxpose on OpenCV's chessboard images against OpenCV's reference poses and
    `cv2.solvePnP`.

    The reference pose of each image is the calibration's own extrinsics
    (`left_intrinsics.yml`, row `i` for the `i`-th image in name order; the file's own
    per-view errors confirm the order). Reprojection errors are RMS in image pixels
    (distortion applied by `cv2.projectPoints`); jaxpose minimises Eq. 8 on undistorted
    pixels (`undistorted_px`), OpenCV on distorted ones, hence differences of a few 1e-3
    px."""
    fs = cv2.FileStorage(str(data / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat()
    extrinsics = fs.getNode("extrinsic_parameters").mat()
    per_view = fs.getNode("per_view_reprojection_errors").mat().ravel()
    cols, rows_ = int(fs.getNode("board_width").real()), int(fs.getNode("board_height").real())
    square = fs.getNode("square_size").real()
    fs.release()
    board = np.zeros((cols * rows_, 3))
    board[:, :2] = np.mgrid[0:cols, 0:rows_].T.reshape(-1, 2) * square
    paths = sorted(data.glob("left*.jpg"))
    if len(paths) != len(extrinsics):
        raise ValueError(f"{len(paths)} images but {len(extrinsics)} reference poses in {data}")

    def rms(corners, rv, tv, distortion):
        p, _ = cv2.projectPoints(board, rv, tv, K, distortion)
        return float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - corners) ** 2, axis=1))))

    images = []
    for path, ext, view_err in zip(paths, extrinsics, per_view, strict=True):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        found, corners = cv2.findChessboardCorners(gray, (cols, rows_))
        if not found:
            images.append({"image": path.name, "found": False})
            continue
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit).reshape(-1, 2)
        rv_ref, tv_ref = ext[:3].reshape(3, 1), ext[3:].reshape(3, 1)
        # The detector may list the corners from the other end of the board.
        flipped = rms(corners[::-1], rv_ref, tv_ref, dist) < rms(corners, rv_ref, tv_ref, dist)
        if flipped:
            corners = np.ascontiguousarray(corners[::-1])
        t0 = time.perf_counter()
        ok, rv_jp, tv_jp = jp.solve_pnp(board, corners, K, dist, method=method)
        seconds = time.perf_counter() - t0
        _, rv_cv, tv_cv = cv2.solvePnP(board, corners, K, dist)
        undist = jp.undistort_pixels(corners, K, dist)
        poses = {"reference": (rv_ref, tv_ref), "cv2": (rv_cv, tv_cv), "jaxpose": (rv_jp, tv_jp)}
        Rs = {k: cv2.Rodrigues(np.asarray(v[0], np.float64))[0] for k, v in poses.items()}
        ts = {k: np.asarray(v[1], np.float64).ravel() for k, v in poses.items()}

        def diff(a, b):
            dt = np.linalg.norm(ts[a] - ts[b])
            return {
                "rotation_deg": float(rotation_angle_deg(Rs[a][None], Rs[b][None])[0]),
                "translation_mm": float(1000 * dt),
                "translation_pct": float(100 * dt / np.linalg.norm(ts[b])),
            }

        images.append(
            {
                "image": path.name,
                "found": True,
                "corners_reversed": bool(flipped),
                "jaxpose_ok": bool(ok),
                "jaxpose_seconds": seconds,
                "rms_px": {k: rms(corners, *v, dist) for k, v in poses.items()},
                "rms_undistorted_px": {k: rms(undist, *v, None) for k, v in poses.items()},
                "calibration_per_view_px": float(view_err),
                "jaxpose_vs_reference": diff("jaxpose", "reference"),
                "jaxpose_vs_cv2": diff("jaxpose", "cv2"),
                "cv2_vs_reference": diff("cv2", "reference"),
                "distance_m": float(np.linalg.norm(ts["reference"])),
                "rvec": {k: np.asarray(v[0], float).ravel().tolist() for k, v in poses.items()},
                "tvec": {k: ts[k].tolist() for k in poses},
            }
        )
    return {
        "data": str(data.relative_to(ROOT)) if data.is_relative_to(ROOT) else str(data),
        "board": {"inner_corners": [cols, rows_], "square_m": square},
        "K": K.tolist(),
        "dist_coeffs": dist.ravel().tolist(),
        "method": method,
        "images": images,
    }


# --------------------------------------------------------------------------- machine


def machine() -> dict:
    """The machine and the load on it (timings here are from a shared machine)."""
    info = {
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "cpu_count": os.cpu_count(),
        "load_average": list(os.getloadavg()),
    }
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu"] = line.split(":", 1)[1].strip()
                break
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                info["memory_gb"] = round(int(line.split()[1]) / 2**20, 1)
                break
    except OSError:  # pragma: no cover - not Linux
        pass
    try:
        import jax

        info["jax_devices"] = [str(d) for d in jax.devices()]
    except RuntimeError:  # pragma: no cover
        pass
    return info


def versions() -> dict:
    out = {"jaxpose": jp.__version__, "opencv": cv2.__version__}
    for pkg in ("jax", "jaxlib", "numpy", "optimistix", "equinox", "poselib", "matplotlib"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:  # pragma: no cover
            out[pkg] = None
    try:
        out["jaxpose_commit"] = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=10
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):  # pragma: no cover
        out["jaxpose_commit"] = None
    return out


# --------------------------------------------------------------------------- run


def run(
    quick: bool = False,
    out_dir: str | Path | None = None,
    *,
    trials: int | None = None,
    schedule: Schedule | None = None,
    kinds: Sequence[str] = KINDS,
    sigmas: Sequence[float] = SIGMAS,
    ns: Sequence[int] = NS,
    jax_methods: Sequence[str] = JAX_METHODS,
    real_images: bool = True,
    plots: bool = True,
    seed: int = 0,
    console=None,
    tag: str | None = None,
    chunk: int | None = None,
) -> dict:
    """Run the accuracy benchmark; print its tables, write its JSON and plots.

    **Arguments:**
    - `quick`: about 50 trials per cell instead of 500 (see `default_schedule`).
    - `out_dir`: where `accuracy.json` and `accuracy_<kind>.png` go (default
      `benchmarks/results/`).
    - `trials`, `schedule`: override the trials per cell / the whole schedule.
    - `kinds`, `sigmas`, `ns`, `jax_methods`: a smaller grid (tests use one).
    - `real_images`: also run the chessboard images; `plots`: write the PNGs.
    - `seed`: the instances' base seed; `console`: a `rich.console.Console` (default:
      a new one); `tag`: appended to the file names (`accuracy{tag}.json`,
      `accuracy{tag}_<kind>.png`; default `"_quick"` in quick mode, else none);
      `chunk`: problems per `solve_pnp_batch` call (default `chunk_size(n, method)`).

    **Returns:** the JSON-ready result (also written to `out_dir / f"accuracy{tag}.json"`).
    """
    from rich.console import Console

    console = console or Console(width=None if sys.stdout.isatty() else 160)
    out = Path(out_dir) if out_dir is not None else RESULTS
    tag = ("_quick" if quick else "") if tag is None else tag
    out.mkdir(parents=True, exist_ok=True)
    schedule = schedule or default_schedule(quick, trials)
    start = time.perf_counter()
    load_start = list(os.getloadavg())
    cells: dict[tuple, dict] = {}
    reproducers: list[dict] = []
    synthetic: dict[str, dict] = {}

    def say(msg):
        console.log(msg)

    for kind in kinds:
        sweeps = {
            "sigma": [(SIGMA_SWEEP_N, float(s)) for s in sigmas],
            "n": [(int(n), N_SWEEP_SIGMA) for n in ns],
        }
        synthetic[kind] = {}
        for sweep, grid in sweeps.items():
            results = []
            for n, sigma in grid:
                key = (kind, n, sigma)
                if key not in cells:
                    cell = make_cell(kind, n, sigma, schedule.cell_trials(n), seed)
                    cells[key] = run_cell(cell, schedule, jax_methods, reproducers, say, chunk)
                results.append(cells[key])
            fixed = {"sigma": {"n": SIGMA_SWEEP_N}, "n": {"sigma": N_SWEEP_SIGMA}}[sweep]
            synthetic[kind][sweep] = fixed | {
                "values": [c[sweep] for c in results],
                "cells": results,
            }
    for rep in reproducers:
        if rep["method"] == jaxpose_name("mixed"):
            say(f"diagnosing a miss of jaxpose mixed ({rep['kind']}, n={rep['n']})")
            rep["jaxpose_solve"] = diagnose(rep)
    optimum = at_optimum(cells.values(), kinds)
    result = {
        "benchmark": "accuracy",
        "mode": "quick" if quick else "full",
        "protocol": {
            "focal_px": FOCAL,
            "kinds": list(kinds),
            "sigma_sweep": {"n": SIGMA_SWEEP_N, "sigma_px": list(map(float, sigmas))},
            "n_sweep": {"sigma_px": N_SWEEP_SIGMA, "n": list(map(int, ns))},
            "rotation_error": "largest angle between matching axes of R_true, R_est (deg)",
            "translation_error": "|t_est - t_true| / |t_true| (%)",
            "frame": "camera (cv2: x_cam = R X + t)",
            "ml_optimum": "best Eq. 8 RMS error of cv2.solvePnPRefineLM from SQPnP, EPnP and "
            f"the true pose (criteria {list(REFINE_CRITERIA)})",
            "at_optimum": f"RMS error within {ABS_TOL:g} px of the ML optimum's "
            f"(at_optimum_abs); within a relative {REL_TOL:g} (at_optimum_rel)",
            "local_minimum": f"more than {LOCAL_MINIMUM:g} px above the ML optimum",
            "poselib": f"estimate_absolute_pose, max_reproj_error {POSELIB_THRESHOLD:g} px, "
            "TRIVIAL loss (least squares)",
            "jaxpose": "solve_pnp_batch (float64), fixed chunks; C(n,3) > 2000 triplets: "
            "a fixed sample of 2000",
            "seed": seed,
        },
        "schedule": {
            "trials": schedule.trials,
            "large_n": {str(k): v for k, v in schedule.large_n.items()},
            "ablation": {
                m: {str(k): v for k, v in d.items()} for m, d in schedule.ablation.items()
            },
            "chunk": {
                str(n): {m: chunk or chunk_size(n, m) for m in jax_methods}
                for n in sorted({SIGMA_SWEEP_N, *ns})
            },
        },
        "synthetic": synthetic,
        "at_optimum": optimum,
        "reproducers": reproducers,
    }
    if real_images:
        say("chessboard images")
        result["chessboard"] = chessboard()
    result["machine"] = machine() | {"load_average_start": load_start}
    result["versions"] = versions()
    result["seconds"] = time.perf_counter() - start
    path = out / f"accuracy{tag}.json"
    path.write_text(json.dumps(result, indent=1))
    if plots:
        result["plots"] = [str(p) for p in plot(result, out, tag)]
        path.write_text(json.dumps(result, indent=1))
    print_tables(result, console)
    console.print(f"wrote {path} ({result['seconds']:.0f} s)")
    return result


def at_optimum(cells, kinds: Sequence[str]) -> dict:
    """Per kind and method: the trials at the ML optimum over every cell of the kind."""
    out: dict[str, dict] = {kind: {} for kind in kinds}
    for cell in cells:
        for name, row in cell["methods"].items():
            if name == ML or not row.get("trials"):
                continue
            acc = out[cell["kind"]].setdefault(
                name,
                {"trials": 0, "at_optimum_abs": 0, "at_optimum_rel": 0, "local_minima": 0}
                | {"failed": 0, "below_reference": 0},
            )
            for k in acc:
                acc[k] += row[k]
    for rows in out.values():
        for acc in rows.values():
            acc["share_abs"] = acc["at_optimum_abs"] / acc["trials"]
            acc["share_rel"] = acc["at_optimum_rel"] / acc["trials"]
    return out


# --------------------------------------------------------------------------- output


def _table_rows(result: dict, kind: str, sweep: str):
    """(header, rows) of the medians table of one sweep: 'rotation deg / translation %'."""
    block = result["synthetic"][kind][sweep]
    header = [str(v) if sweep == "n" else f"{v:g}" for v in block["values"]]
    names = [ML] + [m for m in block["cells"][0]["methods"] if m != ML]
    rows = []
    for name in names:
        cells = []
        for cell in block["cells"]:
            row = cell["methods"].get(name)
            if not row or not row.get("trials"):
                cells.append("-")
                continue
            rot, tr = row["rotation_deg"]["median"], row["translation_pct"]["median"]
            text = "-" if rot is None else f"{rot:.3f} / {tr:.3f}"
            if row["trials"] != cell["trials"]:
                text += f" [{row['trials']}]"
            if row["failed"]:
                text += f" ({row['failed']} failed)"
            cells.append(text)
        rows.append((name, cells))
    return header, rows


LEGEND = (
    "[k]: over the first k trials of the cell only; (f failed): no pose returned (left "
    "out of the medians); -: not run"
)


def _optimum_cell(acc: dict | None) -> str:
    if not acc:
        return "-"
    share = 100 * acc["share_abs"]
    text = f"{share:.2f}% ({acc['at_optimum_abs']}/{acc['trials']})"
    notes = []
    if acc["failed"]:
        notes.append(f"{acc['failed']} failed")
    if acc["local_minima"]:
        notes.append(f"{acc['local_minima']} > {LOCAL_MINIMUM:g} px above")
    return text + "".join(f", {x}" for x in notes)


def print_tables(result: dict, console) -> None:
    """The tables, with rich: medians per sweep and kind, the at-the-optimum shares, the
    chessboard images."""
    from rich.table import Table

    for kind, sweeps in result["synthetic"].items():
        for sweep, block in sweeps.items():
            header, rows = _table_rows(result, kind, sweep)
            fixed = f"n = {block['n']}" if sweep == "sigma" else f"sigma = {block['sigma']:g} px"
            label = "sigma (px)" if sweep == "sigma" else "n"
            trials = ", ".join(str(c["trials"]) for c in block["cells"])
            table = Table(
                title=f"{kind}, {fixed}: median rotation error (deg) / translation error (%)"
                f"\ntrials per cell: {trials}",
                title_justify="left",
                caption=LEGEND,
                caption_justify="left",
            )
            table.add_column(f"method \\ {label}")
            for h in header:
                table.add_column(h, justify="right")
            for name, cells in rows:
                table.add_row(name, *cells)
            console.print(table)
    table = Table(
        title=f"Trials at the ML optimum (RMS within {ABS_TOL:g} px), all cells of each kind",
        title_justify="left",
    )
    table.add_column("method")
    kinds = list(result["at_optimum"])
    for kind in kinds:
        table.add_column(kind, justify="right")
    names = list(dict.fromkeys(n for k in kinds for n in result["at_optimum"][k]))
    for name in names:
        table.add_row(name, *(_optimum_cell(result["at_optimum"][k].get(name)) for k in kinds))
    console.print(table)
    if "chessboard" in result:
        table = Table(title="OpenCV chessboard images (left camera)", title_justify="left")
        for col in (
            "image",
            "rot. vs ref (deg)",
            "trans. vs ref (mm)",
            "rot. vs cv2 (deg)",
            "trans. vs cv2 (mm)",
            "RMS ref (px)",
            "RMS cv2",
            "RMS jaxpose",
            "undist. cv2",
            "undist. jaxpose",
        ):
            table.add_column(col, justify="right")
        for im in result["chessboard"]["images"]:
            if not im["found"]:
                table.add_row(im["image"], *(["not found"] + ["-"] * 8))
                continue
            a, b = im["jaxpose_vs_reference"], im["jaxpose_vs_cv2"]
            e, u = im["rms_px"], im["rms_undistorted_px"]
            table.add_row(
                im["image"],
                f"{a['rotation_deg']:.4f}",
                f"{a['translation_mm']:.3f}",
                f"{b['rotation_deg']:.2e}",
                f"{b['translation_mm']:.2e}",
                f"{e['reference']:.4f}",
                f"{e['cv2']:.4f}",
                f"{e['jaxpose']:.4f}",
                f"{u['cv2']:.4f}",
                f"{u['jaxpose']:.4f}",
            )
        console.print(table)


def markdown(result: dict) -> str:
    """The tables as Markdown (for the README)."""
    lines = []
    for kind, sweeps in result["synthetic"].items():
        for sweep, block in sweeps.items():
            header, rows = _table_rows(result, kind, sweep)
            fixed = f"n = {block['n']}" if sweep == "sigma" else f"sigma = {block['sigma']:g} px"
            label = "sigma (px)" if sweep == "sigma" else "n"
            trials = ", ".join(str(c["trials"]) for c in block["cells"])
            lines += [
                f"**{kind.replace('_', '-')}, {fixed}**: median rotation error (deg) / "
                f"translation error (%); trials per cell: {trials}. {LEGEND}.",
                "",
                f"| method \\ {label} | " + " | ".join(header) + " |",
                "|---|" + "---|" * len(header),
            ]
            lines += [f"| {name} | " + " | ".join(cells) + " |" for name, cells in rows]
            lines.append("")
    kinds = list(result["at_optimum"])
    names = list(dict.fromkeys(n for k in kinds for n in result["at_optimum"][k]))
    lines += [
        f"**At the ML optimum** (RMS reprojection error within {ABS_TOL:g} px of the "
        "reference), over all cells of each kind:",
        "",
        "| method | " + " | ".join(k.replace("_", "-") for k in kinds) + " |",
        "|---|" + "---|" * len(kinds),
    ]
    for name in names:
        cells = [_optimum_cell(result["at_optimum"][k].get(name)) for k in kinds]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("")
    if "chessboard" in result:
        lines += [
            "**OpenCV chessboard images** (jaxpose mixed; reference = OpenCV's calibration "
            "extrinsics; RMS reprojection error in image pixels, and on undistorted pixels, "
            "the criterion jaxpose minimises):",
            "",
            "| image | rotation vs reference (deg) | translation vs reference (mm) | "
            "rotation vs cv2.solvePnP (deg) | translation vs cv2.solvePnP (mm) | "
            "RMS reference | RMS cv2.solvePnP | RMS jaxpose | undistorted: cv2 | "
            "undistorted: jaxpose |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for im in result["chessboard"]["images"]:
            if not im["found"]:
                lines.append(f"| {im['image']} | corners not found |||||||||")
                continue
            a, b = im["jaxpose_vs_reference"], im["jaxpose_vs_cv2"]
            e, u = im["rms_px"], im["rms_undistorted_px"]
            lines.append(
                f"| {im['image']} | {a['rotation_deg']:.4f} | {a['translation_mm']:.3f} | "
                f"{b['rotation_deg']:.1e} | {b['translation_mm']:.1e} | "
                f"{e['reference']:.4f} | {e['cv2']:.4f} | {e['jaxpose']:.4f} | "
                f"{u['cv2']:.4f} | {u['jaxpose']:.4f} |"
            )
        lines.append("")
    return "\n".join(lines)


def plot(result: dict, out: Path, tag: str = "") -> list[Path]:
    """One figure per kind: median rotation and translation errors versus sigma (n = 10)
    and versus n (sigma = 2 px), every method and the ML optimum (dashed, on top). A
    method that ran on only a prefix of some cell's trials is drawn dotted and hollow."""
    from matplotlib.figure import Figure

    paths = []
    for kind, sweeps in result["synthetic"].items():
        fig = Figure(figsize=(12, 9), layout="constrained")
        axes = fig.subplots(2, 2)
        for col, sweep in enumerate(("sigma", "n")):
            if sweep not in sweeps:
                continue
            block = sweeps[sweep]
            x = np.asarray(block["values"], float)
            names = [m for m in block["cells"][0]["methods"] if m != ML] + [ML]
            for row, (metric, unit) in enumerate(
                (("rotation_deg", "rotation error (deg)"), ("translation_pct", "translation (%)"))
            ):
                ax = axes[row, col]
                for k, name in enumerate(names):
                    y, partial = [], False
                    for cell in block["cells"]:
                        r = cell["methods"].get(name, {})
                        v = r.get(metric, {}).get("median") if r.get("trials") else None
                        y.append(np.nan if v is None else v)
                        partial |= bool(r.get("trials")) and r["trials"] != cell["trials"]
                    if name == ML:
                        style = {"color": "black", "ls": "--", "lw": 2, "zorder": 10}
                    else:
                        style = {"color": f"C{k % 10}", "ls": ":" if partial else "-"}
                        if partial:
                            style["mfc"] = "none"
                    marker = "o" if name.startswith("jaxpose") else "s"
                    ax.plot(x, y, marker=marker, ms=4, label=name, **style)
                if sweep == "n":
                    ax.set_xscale("log")
                    ax.set_xticks(x, [str(int(v)) for v in x])
                    ax.set_xlabel(f"n (sigma = {block['sigma']:g} px)")
                else:
                    ax.set_xlabel(f"sigma (px), n = {block['n']}")
                ax.set_yscale("log")
                ax.set_ylabel(f"median {unit}")
                ax.grid(True, which="both", alpha=0.3)
        axes[0, 0].legend(fontsize=7, ncol=2)
        fig.suptitle(
            f"{kind.replace('_', '-')} scenes: median errors ({result['mode']} run; dotted, "
            "hollow: a method run on the first trials of some cells only)"
        )
        path = out / f"accuracy{tag}_{kind}.png"
        fig.savefig(path, dpi=110)
        paths.append(path)
    return paths


# --------------------------------------------------------------------------- command line


def enable_compilation_cache() -> None:
    """JAX's persistent compilation cache (shared with the `jaxpose` command): a second run
    loads its 28 compiled `(n, method)` programs instead of compiling them again."""
    import jax

    cache = Path.home() / ".cache" / "jaxpose" / "xla"
    try:
        cache.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(cache))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except OSError:  # pragma: no cover - read-only home
        pass


def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="about 50 trials per cell")
    parser.add_argument("--trials", type=int, default=None, help="trials per cell (small n)")
    parser.add_argument("--out", default=None, help="output folder (default benchmarks/results)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    parser.add_argument("--no-images", action="store_true", help="skip the chessboard images")
    parser.add_argument("--markdown", default=None, help="also write the tables as Markdown")
    parser.add_argument(
        "--from-json", default=None, help="no run: tables and plots from a saved result"
    )
    args = parser.parse_args(argv)
    if args.from_json:
        from rich.console import Console

        path = Path(args.from_json)
        result = json.loads(path.read_text())
        tag = path.stem.removeprefix("accuracy")
        plot(result, Path(args.out) if args.out else path.parent, tag)
        print_tables(result, Console(width=None if sys.stdout.isatty() else 160))
        if args.markdown:
            Path(args.markdown).write_text(markdown(result))
        return result
    if args.trials is not None and args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    enable_compilation_cache()
    result = run(
        args.quick,
        args.out,
        trials=args.trials,
        kinds=args.kinds,
        seed=args.seed,
        real_images=not args.no_images,
    )
    if args.markdown:
        Path(args.markdown).write_text(markdown(result))
    return result


if __name__ == "__main__":
    main()
