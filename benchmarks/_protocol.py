"""The standard synthetic PnP protocol (the RPnP / OPnP / MLPnP toolboxes'), shared by
`benchmarks/accuracy.py` and `benchmarks/float32.py`: the seeded scenes of a cell, the
methods that solve them (jaxpose, OpenCV, PoseLib), the ML optimum they are measured
against, the error metrics and their statistics.

Scenes: `jaxpose.apps.random_scene` with `f = 800`, OpenCV's convention (world = camera
frame, `C = K [I | 0]`) and camera-frame points uniform in `[-2,2]x[-2,2]x[4,8]`
("ordinary"), `[1,2]x[1,2]x[4,8]` ("quasi_singular") or on a plane `[-2,2]^2` tilted by
up to 30 degrees at depth 4-8 ("planar"); Gaussian pixel noise `sigma`. Errors, in the
camera frame (`x_cam = R X + t`): rotation error = the largest angle between matching
axes (columns) of `R_true` and `R_est` (degrees); translation error =
`|t_est - t_true| / |t_true|` (%).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import cv2
import numpy as np
from jaxtyping import Bool, Float

import jaxpose as jp
from benchmarks._harness import Stopwatch, rotation_angle, timeit

KINDS = ("ordinary", "quasi_singular", "planar")
FOCAL = 800.0
JAX_METHODS = tuple(jp.api.METHODS)  # ("mixed", "three_point", "linear", "nonlinear")
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


def jaxpose_name(method: str) -> str:
    return f"jaxpose {method}"


def method_names(kind: str, jax_methods: Sequence[str] = JAX_METHODS) -> list[str]:
    """The methods run on scenes of `kind`, in table order (IPPE on planar scenes only)."""
    cv = [f"cv2 {k}" for k in OPENCV_FLAGS if k != "IPPE" or kind == "planar"]
    return [jaxpose_name(m) for m in jax_methods] + cv + ["PoseLib"]


def chunk_size(n: int, method: str = "mixed") -> int:
    """Problems per `solve_pnp_batch` call at `n` matches (a fixed shape: one compilation
    per `(n, method)`; the last chunk is padded). Bounded by memory: the linear and LM
    steps hold about `triplets x n` rows per problem; the non-linear method runs LM on
    every triplet, so it gets half as many problems once that is large."""
    rows = len(jp.strategy.triplet_indices(n, 2000)) * n
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
    return np.degrees(rotation_angle(R_a, R_b))


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
    """`trials` instances of `jaxpose.apps.random_scene` (OpenCV's convention, so the scene's
    model-to-world pose is the camera-frame pose). One generator per cell, seeded by
    `(seed, kind, n, sigma)`: a shorter run's trials are a prefix of a longer run's."""
    key = (seed, KINDS.index(kind), n, round(sigma * 1000))
    rng = np.random.default_rng(key)
    scenes = [
        jp.apps.random_scene(rng, n, noise=sigma, kind=kind, focal=FOCAL, world_camera=False)
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
    watch = Stopwatch()
    first = None
    for s in range(0, trials, chunk):
        idx = np.minimum(np.arange(s, s + chunk), trials - 1)  # pad with the last trial
        obj, img = cell.obj[idx], cell.img[idx]
        call = timeit(
            lambda: jp.solve_pnp_batch(obj, img, cell.K, method=method),
            warmup=0,
            repeat=1,
        )
        okb, rv, tv = call.result
        first = call.best if first is None else first
        m = min(chunk, trials - s)
        R[s : s + m], t[s : s + m], ok[s : s + m] = rotvec_to_matrix(rv[:m]), tv[:m], okb[:m]
    return Answers(R, t, ok, watch.seconds, {"chunk": chunk, "first_call_s": first})


def solve_opencv(cell: Cell, flag: int, trials: int) -> Answers:
    """`cv2.solvePnP` with `flag`, one call per trial (an OpenCV error is a failure)."""
    R, t, ok = _empty(trials)
    watch = Stopwatch()
    for i in range(trials):
        try:
            good, rv, tv = cv2.solvePnP(cell.obj[i], cell.img[i], cell.K, None, flags=flag)
        except cv2.error:
            continue
        if good:
            R[i], t[i], ok[i] = cv2.Rodrigues(rv)[0], tv.ravel(), True
    return Answers(R, t, ok, watch.seconds)


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
    watch = Stopwatch()
    for i in range(trials):
        pose, _ = poselib.estimate_absolute_pose(cell.img[i], cell.obj[i], camera, ransac, bundle)
        R[i], t[i], ok[i] = pose.R, pose.t, True
    return Answers(R, t, ok, watch.seconds)


def ml_optimum(cell: Cell, trials: int) -> tuple[Answers, np.ndarray, list[str]]:
    """The reference: for each trial, the lowest Eq. 8 error of `cv2.solvePnPRefineLM`
    started from SQPnP, EPnP and the true pose. Returns the answers, their RMS errors
    and which start won."""
    R, t, ok = _empty(trials)
    err = np.full(trials, np.inf)
    won: list[str] = []
    watch = Stopwatch()
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
    return Answers(R, t, ok, watch.seconds), err, won


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
