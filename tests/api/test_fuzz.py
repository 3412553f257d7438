"""Fuzz and property suite: hostile and degenerate input across the public entry points.

Generated cases go through a few jit-compiled, vmapped calls of fixed shapes (compiling is
the expensive part, a case costs microseconds), hypothesis drives the argument-validation
paths. Expectations:

- invalid arguments raise `ValueError` naming the argument;
- valid but degenerate problems come back not accepted, with a status that says why;
- no NaN or inf ever comes out of finite input, nor out of a solver given NaN or inf
  (those report `Status.NOT_FINITE`);
- valid problems give the true pose (noise-free) or OpenCV's float64 optimum (SQPnP then
  `solvePnPRefineLM`, noisy).

`CASES` counts the generated cases; `test_case_count` asserts it (its id shows it).
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import textwrap

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxpose as jp
from jaxpose.apps._bench import random_rotations
from jaxpose.geometry._validate import check_problem

ROT_BATCH = 2**14  # per rotation group and dtype
CAMERA_BATCH = 2**14  # per dtype
TRIPLET_BATCH = 2**14  # three_point / p3p, per dtype
LINEAR_BATCH = 2**12
NONLINEAR_BATCH = 2**10
SOLVE_BATCH = {"float64": 2**11, "float32": 2**10}
VMAP_BATCH = 2**7  # of the float64 problems, also through `jax.vmap(solve)`
NON_FINITE_BATCH = 2**8
PNP_BATCH = 2**10
HYPOTHESIS_EXAMPLES = 150  # per validation test
N_POINTS = 6  # matches per generated problem (masks make 0-6 of them active)

ROT_GROUPS = ("rotvec", "quaternion", "rpy", "project")
CASES = {
    "rotations": len(ROT_GROUPS) * ROT_BATCH * 2,
    "camera": CAMERA_BATCH * 2,
    "three_point": TRIPLET_BATCH * 2,
    "p3p": TRIPLET_BATCH * 2,
    "linear": LINEAR_BATCH,
    "nonlinear": NONLINEAR_BATCH,
    "solve": sum(SOLVE_BATCH.values()),
    "solve_non_finite": SOLVE_BATCH["float64"],
    "solve_pnp_batch": PNP_BATCH,
}  # plus up to HYPOTHESIS_EXAMPLES per argument-validation test
TOTAL_CASES = sum(CASES.values())

DTYPES = ("float64", "float32")
EPS = {"float64": float(np.finfo(np.float64).eps), "float32": float(np.finfo(np.float32).eps)}
VALID_STATUSES = {int(s) for s in jp.Status}


def _finite(*trees) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(x)))) for x in jax.tree.leaves(trees))


def _angle(A, B):
    """Angle between rotations (numpy, float64; accurate near 0, unlike arccos)."""
    A, B = np.asarray(A, np.float64), np.asarray(B, np.float64)
    chord = np.linalg.norm(A - B, axis=(-2, -1)) / (2 * np.sqrt(2))
    return 2 * np.arcsin(np.clip(chord, 0, 1))


def _orthonormality(R):
    R = np.asarray(R, np.float64)
    eye = np.eye(3)
    off = np.max(np.abs(np.swapaxes(R, -1, -2) @ R - eye), axis=(-2, -1))
    return np.maximum(off, np.abs(np.linalg.det(R) - 1))


def _unit(rng, B):
    v = rng.normal(size=(B, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _pick(rng, B, options):
    """One of several generated columns per row (options: list of (B, ...) arrays)."""
    which = rng.integers(0, len(options), B)
    out = np.array(options[0], copy=True)
    for i, o in enumerate(options[1:], 1):
        out[which == i] = o[which == i]
    return out


# --------------------------------------------------------------------------- rotations


@jax.jit
def _rotvec_group(r):
    R = jax.vmap(jp.rotvec_to_matrix)(r)
    r2 = jax.vmap(jp.matrix_to_rotvec)(R)
    q = jax.vmap(jp.geometry.rotvec_to_quaternion)(r)
    return {
        "R": R,
        "R_back": jax.vmap(jp.rotvec_to_matrix)(r2),
        "r2": r2,
        "q": q,
        "R_q": jax.vmap(jp.geometry.quaternion_to_matrix)(q),
        "R_qr": jax.vmap(jp.rotvec_to_matrix)(jax.vmap(jp.geometry.quaternion_to_rotvec)(q)),
        "q_R": jax.vmap(jp.geometry.matrix_to_quaternion)(R),
        "angle": jax.vmap(jp.geometry.rotation_angle)(R),
        "self_distance": jax.vmap(jp.geometry.rotation_distance)(R, R),
        "d_to_rotvec": jax.vmap(jax.jacfwd(jp.matrix_to_rotvec))(R),
        "d_to_matrix": jax.vmap(jax.jacrev(jp.rotvec_to_matrix))(r),
        "d_angle": jax.vmap(jax.grad(jp.geometry.rotation_angle))(R),
    }


@jax.jit
def _quaternion_group(q, p, qv):
    return {
        "R": jax.vmap(jp.geometry.quaternion_to_matrix)(q),
        "r": jax.vmap(jp.geometry.quaternion_to_rotvec)(q),
        "R_r": jax.vmap(jp.rotvec_to_matrix)(jax.vmap(jp.geometry.quaternion_to_rotvec)(q)),
        "R_pq": jax.vmap(jp.geometry.quaternion_to_matrix)(
            jax.vmap(jp.geometry.quaternion_multiply)(p, q)
        ),
        "R_p": jax.vmap(jp.geometry.quaternion_to_matrix)(p),
        "R_qv": jax.vmap(jp.geometry.quaternion_vector_to_matrix)(qv),
        "d_qv": jax.vmap(jax.jacfwd(jp.geometry.quaternion_vector_to_matrix))(qv),
        "d_q": jax.vmap(jax.jacfwd(jp.geometry.quaternion_to_rotvec))(q),
    }


@jax.jit
def _rpy_group(rpy):
    R = jax.vmap(jp.geometry.rpy_to_matrix)(rpy)
    a, b, singular = jax.vmap(jp.geometry.matrix_to_rpy)(R)
    return {
        "R": R,
        "a": a,
        "b": b,
        "singular": singular,
        "R_a": jax.vmap(jp.geometry.rpy_to_matrix)(a),
        "R_b": jax.vmap(jp.geometry.rpy_to_matrix)(b),
        "d_rpy": jax.vmap(jax.jacfwd(lambda R: jp.geometry.matrix_to_rpy(R)[0]))(R),
    }


@jax.jit
def _project_group(M):
    return {
        "R": jax.vmap(jp.geometry.project_to_rotation)(M),
        "d": jax.vmap(jax.jacfwd(jp.geometry.project_to_rotation))(M),
    }


def _rotation_inputs(rng, dtype):
    B = ROT_BATCH
    axis = _unit(rng, B)
    angle = _pick(
        rng,
        B,
        [
            rng.uniform(0, np.pi, B),
            np.zeros(B),
            10 ** rng.uniform(-12, -2, B),
            np.pi - 10 ** rng.uniform(-12, -2, B),
            np.full(B, np.pi),
            rng.uniform(np.pi, 4 * np.pi, B),
            10 ** rng.uniform(-300, -20, B),
        ],
    )
    r = axis * angle[:, None]
    q = rng.normal(size=(B, 4))
    q = _pick(
        rng,
        B,
        [
            q,
            q * 10 ** rng.uniform(-15, 15, (B, 1)),
            np.zeros((B, 4)),
            q * np.array([0, 1, 1, 1]),  # half-turns
            q * np.array([1, 1e-9, 1e-9, 1e-9]),  # near the identity
            -q,
        ],
    )
    p = rng.normal(size=(B, 4))
    qv = (
        _unit(rng, B)
        * _pick(
            rng,
            B,
            [
                rng.uniform(0, 1, B),
                np.zeros(B),
                np.ones(B),
                1 - 10 ** rng.uniform(-12, -2, B),
                1 + 10 ** rng.uniform(-12, 2, B),
            ],
        )[:, None]
    )
    pitch = _pick(
        rng,
        B,
        [
            rng.uniform(-np.pi / 2, np.pi / 2, B),
            np.full(B, np.pi / 2),
            np.full(B, -np.pi / 2),
            np.pi / 2 - 10 ** rng.uniform(-12, -2, B),
            -np.pi / 2 + 10 ** rng.uniform(-12, -2, B),
            rng.uniform(-np.pi, np.pi, B),
        ],
    )
    rpy = np.column_stack([rng.uniform(-np.pi, np.pi, B), pitch, rng.uniform(-np.pi, np.pi, B)])
    Rs = random_rotations(rng, B)
    M = _pick(
        rng,
        B,
        [
            Rs + 10 ** rng.uniform(-12, 0, (B, 1, 1)) * rng.normal(size=(B, 3, 3)),
            Rs * 10 ** rng.uniform(-10, 10, (B, 1, 1)),
            np.zeros((B, 3, 3)),
            np.einsum("bi,bj->bij", rng.normal(size=(B, 3)), rng.normal(size=(B, 3))),
            Rs @ np.diag([1.0, 1.0, 0.0]),
            Rs @ np.diag([1.0, 1.0, -1.0]),
            rng.normal(size=(B, 3, 3)),
        ],
    )
    cast = lambda x: np.asarray(x, dtype)
    return cast(r), cast(q), cast(p), cast(qv), cast(rpy), cast(M), Rs, angle


_quaternions_to_matrices = jax.jit(jax.vmap(jp.geometry.quaternion_to_matrix))


@pytest.mark.parametrize("dtype", DTYPES)
def test_rotations(dtype):
    rng = np.random.default_rng(10 + DTYPES.index(dtype))
    r, q, p, qv, rpy, M, Rs, angle = _rotation_inputs(rng, dtype)
    eps = EPS[dtype]
    tol = 64 * eps

    out = jax.tree.map(np.asarray, _rotvec_group(r))
    assert _finite(out), [k for k, v in out.items() if not _finite(v)]
    assert np.max(_orthonormality(out["R"])) < tol
    assert np.max(np.linalg.norm(out["r2"], axis=1)) <= np.pi * (1 + tol)
    for key in ("R_back", "R_q", "R_qr"):
        assert np.max(np.abs(out[key] - out["R"])) < tol, key
    q_ref = np.asarray(out["q"], np.float64)
    assert np.max(np.abs(np.linalg.norm(q_ref, axis=1) - 1)) < tol
    sign = np.sign(np.sum(q_ref * out["q_R"], axis=1, keepdims=True))
    assert np.max(np.abs(out["q_R"] * sign - q_ref)) < 1e3 * tol  # q is ill-posed near pi
    theta = np.linalg.norm(np.asarray(r, np.float64), axis=1)
    wrapped = np.abs((theta + np.pi) % (2 * np.pi) - np.pi)
    np.testing.assert_allclose(out["angle"], wrapped, rtol=0, atol=4 * np.pi * tol)
    assert np.max(np.abs(out["self_distance"])) < np.sqrt(eps)

    R_ref = lambda q: np.asarray(_quaternions_to_matrices(q / np.linalg.norm(q, axis=1)[:, None]))
    out = jax.tree.map(np.asarray, _quaternion_group(q, p, qv))
    assert _finite(out), [k for k, v in out.items() if not _finite(v)]
    assert np.max(_orthonormality(out["R"])) < tol
    assert np.max(_orthonormality(out["R_qv"])) < tol
    assert np.max(np.abs(out["R_r"] - out["R"])) < tol
    q64 = np.asarray(q, np.float64)
    nonzero = np.linalg.norm(q64, axis=1) > 0
    assert np.max(np.abs(out["R_pq"] - out["R_p"] @ out["R"])[nonzero]) < tol
    assert np.max(np.abs(out["R"][nonzero] - R_ref(q64[nonzero]))) < tol
    assert np.all(out["R"][~nonzero] == np.eye(3))

    out = jax.tree.map(np.asarray, _rpy_group(rpy))
    assert _finite(out), [k for k, v in out.items() if not _finite(v)]
    assert np.max(np.abs(out["R_a"] - out["R"])) < tol
    assert np.max(np.abs(out["R_b"] - out["R"])) < tol
    assert np.all(np.abs(out["a"]) <= np.pi * (1 + eps)) and np.all(np.abs(out["b"]) <= np.pi)
    exact_lock = np.abs(np.abs(np.asarray(rpy)[:, 1]) - np.pi / 2) == 0
    assert np.all(out["singular"][exact_lock & (dtype == "float64")])

    out = jax.tree.map(np.asarray, _project_group(M))
    assert _finite(out), [k for k, v in out.items() if not _finite(v)]
    assert np.max(_orthonormality(out["R"])) < tol


# --------------------------------------------------------------------------- camera


@jax.jit
def _camera_group(C, points, pixels, length):
    uv, depth = jax.vmap(jp.geometry.project_with_depth)(C, points)
    centre, directions = jax.vmap(jp.geometry.backproject)(C, pixels)
    K, R, t, centre2 = jax.vmap(jp.geometry.decompose_camera)(C)
    n1, a1, n2, a2 = jax.vmap(jp.geometry.ray_planes)(C, pixels)
    return {
        "uv": jax.vmap(jp.project)(C, points),
        "uv_d": uv,
        "depth": depth,
        "centre": centre,
        "directions": directions,
        "centre2": jax.vmap(jp.geometry.camera_centre)(C),
        "K": K,
        "R": R,
        "t": t,
        "centre3": centre2,
        "normalized": jax.vmap(jp.geometry.normalize_camera)(C),
        "planes": (n1, a1, n2, a2),
        "reprojected": jax.vmap(jp.project)(
            C, centre[:, None] + length[:, None, None] * directions
        ),
    }


_centres = jax.jit(jax.vmap(jp.geometry.camera_centre))


def _camera_inputs(rng, dtype):
    """Cameras of every scale and sign (a quarter singular), world points in front, behind,
    on the focal plane, at the centre, and far away; 4 points and 4 pixels per camera."""
    B = CAMERA_BATCH
    f = 10 ** rng.uniform(1, 4, B)
    K = np.zeros((B, 3, 3))
    K[:, 0, 0], K[:, 1, 1], K[:, 2, 2] = f, f * rng.uniform(0.5, 2, B), 1
    K[:, 0, 1] = rng.uniform(-1, 1, B) * (rng.random(B) < 0.2)
    K[:, :2, 2] = rng.uniform(-500, 1500, (B, 2))
    R = random_rotations(rng, B)
    centre = rng.normal(scale=10 ** rng.uniform(-2, 3, (B, 1)), size=(B, 3))
    t = -np.einsum("bij,bj->bi", R, centre)
    span = 6 if dtype == "float64" else 3
    scale = 10 ** rng.uniform(-span, span, B) * np.where(rng.random(B) < 0.5, -1, 1)
    C = scale[:, None, None] * (K @ np.concatenate([R, t[:, :, None]], axis=2))
    singular = rng.random(B) < 0.25
    C[singular, 2, :3] = 0.3 * C[singular, 0, :3] - 2.0 * C[singular, 1, :3]
    cam_pts = rng.normal(size=(B, 4, 3)) * 10 ** rng.uniform(-3, 3, (B, 4, 1))
    cam_pts[:, :, 2] = _pick(
        rng,
        B * 4,
        [
            np.abs(cam_pts[:, :, 2]).ravel() + 0.1,
            -np.abs(cam_pts[:, :, 2]).ravel() - 0.1,
            np.zeros(B * 4),
        ],
    ).reshape(B, 4)
    cam_pts[rng.random(B) < 0.1, 0] = 0  # the centre itself
    points = np.einsum("bji,bnj->bni", R, cam_pts - t[:, None])
    pixels = rng.uniform(-2000, 3000, (B, 4, 2))
    cast = lambda x: jnp.asarray(x, dtype)
    return cast(C), cast(points), cast(pixels), singular, cam_pts


@pytest.mark.parametrize("dtype", DTYPES)
def test_camera(dtype):
    rng = np.random.default_rng(20 + DTYPES.index(dtype))
    C, points, pixels, singular, cam_pts = _camera_inputs(rng, dtype)
    length = 3.0 * (1 + np.linalg.norm(np.asarray(_centres(C)), axis=1))
    out = jax.tree.map(np.asarray, _camera_group(C, points, pixels, jnp.asarray(length, dtype)))
    assert _finite(out), [k for k, v in out.items() if not _finite(v)]
    eps = EPS[dtype]
    C64 = np.asarray(C, np.float64)
    regular = ~singular
    # Depth: positive in front, negative behind, whatever the camera's sign and scale.
    z = cam_pts[:, :, 2]
    clear = regular[:, None] & (np.abs(z) > 1e-2 * np.linalg.norm(cam_pts, axis=2))
    assert np.all(np.sign(out["depth"][clear]) == np.sign(z[clear]))
    # Pixels: the float64 reference where the point is clear of the focal plane.
    h = (
        np.einsum("bij,bnj->bni", C64[:, :, :3], np.asarray(points, np.float64))
        + C64[:, None, :, 3]
    )
    w = h[..., 2:]
    ref = np.divide(h[..., :2], w, out=np.zeros_like(h[..., :2]), where=w != 0)
    # Forward error bound of the homogeneous product, then of the division.
    hom = np.concatenate([np.abs(np.asarray(points, np.float64)), np.ones_like(w)], axis=2)
    a = np.einsum("bij,bnj->bni", np.abs(C64), hom)
    bound = 16 * eps * (a[..., :2] + np.abs(ref) * a[..., 2:]) / np.maximum(np.abs(w), 1e-300)
    assert np.all((np.abs(out["uv"] - ref) <= bound)[clear])
    np.testing.assert_array_equal(out["uv"], out["uv_d"])
    # Back-projection: every ray goes through its pixel (followed well in front).
    pix = np.asarray(pixels, np.float64)
    cond = np.linalg.cond(C64[:, :, :3])
    good = regular & (cond < 1e3)
    err = np.max(np.abs(out["reprojected"] - pix), axis=(1, 2)) / np.max(np.abs(pix), axis=(1, 2))
    assert np.max(err[good]) < 1e4 * eps
    np.testing.assert_allclose(out["centre"], out["centre2"])
    np.testing.assert_allclose(out["centre"], out["centre3"])
    # Decomposition: lambda K [R | t] = C, R a rotation, K upper triangular, K[2,2] = 1.
    assert np.max(_orthonormality(out["R"][good])) < 1e3 * eps  # Gram-Schmidt: ~cond(M) eps
    assert np.all(np.tril(out["K"], -1) == 0) and np.all(out["K"][:, 2, 2] == 1)
    P = np.einsum("bij,bjk->bik", out["K"], np.concatenate([out["R"], out["t"][:, :, None]], 2))
    lam = np.sum(P * C64, axis=(1, 2)) / np.sum(P * P, axis=(1, 2))
    rel = np.max(np.abs(lam[:, None, None] * P - C64), axis=(1, 2)) / np.max(np.abs(C64), (1, 2))
    assert np.max(rel[good]) < 1e4 * eps
    # Normalised camera: the third row of M has unit norm, det M > 0.
    Mn = out["normalized"][regular, :, :3].astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(Mn[:, 2], axis=1), 1, rtol=64 * eps)
    assert np.all(np.linalg.det(Mn) > 0)
    # Ray planes contain the points that project onto their pixel.
    n1, a1, n2, a2 = (np.asarray(x, np.float64) for x in out["planes"])
    on_ray = out["centre"].astype(np.float64)[:, None] + length[:, None, None] * out["directions"]
    size = np.linalg.norm(n1, axis=2) * np.linalg.norm(on_ray, axis=2) + np.abs(a1)
    res = np.abs(np.sum(n1 * on_ray, axis=2) + a1) / np.maximum(size, 1e-300)
    assert np.max(res[good]) < 1e4 * eps
    del n2, a2


# --------------------------------------------------------------------------- scenes

KINDS = (
    "valid",  # noise-free, ordinary
    "noisy",  # 1 px Gaussian noise
    "planar",  # coplanar points
    "collinear",  # all points on a 3D line
    "near_collinear",  # a line, jittered by 1e-5 of its length
    "duplicated",  # every point the same
    "pairs",  # three distinct points, each twice
    "behind",  # every point behind the camera
    "some_behind",  # half of them behind
    "zero_area",  # on a plane through the camera centre: every image triangle is flat
    "few",  # 3 or 4 active matches (mask)
    "too_few",  # 0 to 2 active matches
    "huge",  # coordinates scaled by 1e3 to 1e7
    "tiny",  # coordinates scaled by 1e-7 to 1e-3
)
KIND = {k: i for i, k in enumerate(KINDS)}
GOOD_KINDS = ("valid", "planar", "huge", "tiny")


def scenes(rng, B, n=N_POINTS, kinds=None):
    """`B` pose problems with world cameras (a quarter in OpenCV's `K [I | 0]`), the camera
    matrix scaled by +-1e-3..1e3; each of a kind in `KINDS` (default: uniformly drawn)."""
    kind = rng.integers(0, len(KINDS), B) if kinds is None else np.asarray(kinds)
    sel = lambda name: kind == KIND[name]
    f = rng.uniform(300, 3000, B)
    K = np.zeros((B, 3, 3))
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = f, f, 320, 240, 1
    opencv = rng.random(B) < 0.25
    R_wc = random_rotations(rng, B)
    R_wc[opencv] = np.eye(3)
    t_wc = rng.normal(scale=2.0, size=(B, 3))
    t_wc[opencv] = 0
    scale = np.ones(B)
    scale[sel("huge")] = 10 ** rng.uniform(3, 7, sel("huge").sum())
    scale[sel("tiny")] = 10 ** rng.uniform(-7, -3, sel("tiny").sum())
    pc = rng.uniform([-2, -2, 4], [2, 2, 8], size=(B, n, 3))
    s = sel("planar")
    slope = rng.uniform(-0.5, 0.5, (s.sum(), 2))
    pc[s, :, 2] = 6 + np.einsum("bnk,bk->bn", pc[s, :, :2], slope)
    start = rng.uniform([-1, -1, 5], [1, 1, 7], size=(B, 1, 3))
    line = start + rng.uniform(-1.5, 1.5, (B, n, 1)) * _unit(rng, B)[:, None]
    for name, jitter in (("collinear", 0.0), ("near_collinear", 3e-5)):
        s = sel(name)
        pc[s] = line[s] + jitter * rng.normal(size=(s.sum(), n, 3))
    pc[sel("duplicated")] = pc[sel("duplicated")][:, :1]
    s = sel("pairs")
    pc[s] = np.concatenate([pc[s][:, : (n + 1) // 2]] * 2, axis=1)[:, :n]
    pc[sel("behind"), :, 2] *= -1
    pc[sel("some_behind"), : n // 2, 2] *= -1
    e1 = rng.normal(size=(B, 3))
    e1[:, 2] = np.abs(e1[:, 2]) + 3
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(e1, _unit(rng, B))
    e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
    uw = rng.uniform([4, -1], [8, 1], size=(B, n, 2))
    flat = uw[..., :1] * e1[:, None] + uw[..., 1:] * e2[:, None]
    pc[sel("zero_area")] = flat[sel("zero_area")]
    pc *= scale[:, None, None]
    t_wc = t_wc * scale[:, None]
    world = np.einsum("bji,bnj->bni", R_wc, pc - t_wc[:, None])
    R = random_rotations(rng, B)
    t = world.mean(axis=1) + rng.normal(scale=0.1, size=(B, 3)) * scale[:, None]
    model = np.einsum("bji,bnj->bni", R, world - t[:, None])
    sign = np.where(rng.random(B) < 0.5, -1.0, 1.0)
    cam_scale = 10 ** rng.uniform(-3, 3, B) * sign
    Rt = np.concatenate([R_wc, t_wc[:, :, None]], axis=2)
    camera = cam_scale[:, None, None] * (K @ Rt)
    h = pc @ np.swapaxes(K, 1, 2)
    image = h[..., :2] / h[..., 2:]
    image[sel("noisy")] += rng.normal(size=(sel("noisy").sum(), n, 2))
    mask = np.ones((B, n), bool)
    for name, lo, hi in (("few", 3, 5), ("too_few", 0, 3)):
        for b in np.flatnonzero(sel(name)):
            mask[b, rng.permutation(n)[rng.integers(lo, hi) :]] = False
    return dict(
        camera=camera,
        model=model,
        image=image,
        mask=mask,
        R=R,
        t=t,
        kind=kind,
        scale=scale,
        K=K,
        R_wc=R_wc,
        t_wc=t_wc,
    )


def _front(camera, R, t, model, mask):
    """Whether every active model point is in front of the camera at pose (R, t)."""
    C = np.asarray(camera, np.float64)
    world = np.einsum("bij,bnj->bni", R, model) + t[:, None]
    h = np.einsum("bj,bnj->bn", C[:, 2, :3], world) + C[:, None, 2, 3]
    depth = h * np.sign(np.linalg.det(C[:, :, :3]))[:, None]
    return np.all((depth > 0) | ~mask, axis=1)


def _eq8(camera, R, t, model, image):
    C = np.asarray(camera, np.float64)
    world = np.einsum("bij,bnj->bni", R, model) + t[:, None]
    h = np.einsum("bij,bnj->bni", C[:, :, :3], world) + C[:, None, :, 3]
    return np.sqrt(np.mean(np.sum((h[..., :2] / h[..., 2:] - image) ** 2, axis=2), axis=1))


# --------------------------------------------------------------------------- three-point


@jax.jit
def _three_point_group(C, model, image, bearings):
    sol = jax.vmap(jp.solvers.three_point)(C, model, image)
    R, t, valid = jax.vmap(jp.solvers.p3p)(bearings, model)
    return sol, (R, t, valid)


TRIPLET_KINDS = (
    "valid",
    "collinear",
    "near_collinear",
    "two_equal",
    "all_equal",
    "behind",
    "zero_area",
    "nan",
    "inf",
    "huge",
    "tiny",
)


def _triplet_inputs(rng, dtype):
    B = TRIPLET_BATCH
    kind = rng.integers(0, len(TRIPLET_KINDS), B)
    s = scenes(rng, B, 3, kinds=np.zeros(B, int))
    pc = rng.uniform([-2, -2, 4], [2, 2, 8], size=(B, 3, 3))
    sel = lambda name: kind == TRIPLET_KINDS.index(name)
    line = pc[:, :1] + rng.uniform(-1, 1, (B, 3, 1)) * _unit(rng, B)[:, None]
    pc[sel("collinear")] = line[sel("collinear")]
    near = line + 1e-4 * rng.normal(size=line.shape)
    pc[sel("near_collinear")] = near[sel("near_collinear")]
    pc[sel("two_equal"), 1] = pc[sel("two_equal"), 0]
    pc[sel("all_equal")] = pc[sel("all_equal")][:, :1]
    pc[sel("behind")] *= -1
    e1 = rng.normal(size=(B, 3)) + np.array([0, 0, 4.0])  # towards the front
    e2 = np.cross(e1, _unit(rng, B))
    e1, e2 = (e / np.linalg.norm(e, axis=1, keepdims=True) for e in (e1, e2))
    flat = rng.uniform(4, 8, (B, 3, 1)) * e1[:, None] + rng.uniform(-1, 1, (B, 3, 1)) * e2[:, None]
    pc[sel("zero_area")] = flat[sel("zero_area")]
    scale = np.ones(B)
    scale[sel("huge")] = 10 ** rng.uniform(3, 7, sel("huge").sum())
    scale[sel("tiny")] = 10 ** rng.uniform(-7, -3, sel("tiny").sum())
    K, R_wc, t_wc = s["K"], s["R_wc"], s["t_wc"] * scale[:, None]
    camera = K @ np.concatenate([R_wc, t_wc[:, :, None]], 2)
    world = np.einsum("bji,bnj->bni", R_wc, pc * scale[:, None, None] - t_wc[:, None])
    R, t = s["R"], world.mean(axis=1)
    model = np.einsum("bji,bnj->bni", R, world - t[:, None])
    h = pc @ np.swapaxes(K, 1, 2)
    image = h[..., :2] / h[..., 2:]
    bearings = pc / np.linalg.norm(pc, axis=2, keepdims=True)
    for name, value in (("nan", np.nan), ("inf", np.inf)):
        rows = np.flatnonzero(sel(name))
        which = rng.integers(0, 3, rows.size)
        for b, w in zip(rows, which, strict=True):
            arr = (camera, model, image)[w]
            arr[(b, *(rng.integers(0, d) for d in arr.shape[1:]))] = value * rng.choice([-1, 1])
    bearings[sel("nan"), 0, 0] = np.nan
    cast = lambda x: jnp.asarray(x, dtype)
    # p3p works in the camera frame: lambda f = (R_wc R) m + t'.
    return kind, cast(camera), cast(model), cast(image), cast(bearings), R, R_wc @ R


@pytest.mark.parametrize("dtype", DTYPES)
def test_three_point_and_p3p(dtype):
    rng = np.random.default_rng(30 + DTYPES.index(dtype))
    kind, C, model, image, bearings, R, R_cam = _triplet_inputs(rng, dtype)
    sol, (pR, pt, pvalid) = _three_point_group(C, model, image, bearings)
    sol = jax.tree.map(np.asarray, sol)
    pR, pt, pvalid = np.asarray(pR), np.asarray(pt), np.asarray(pvalid)
    assert _finite(sol.R, sol.t, pR, pt)
    assert set(np.unique(sol.status)) <= VALID_STATUSES
    assert np.array_equal(sol.status == jp.Status.OK, np.any(sol.valid, axis=1))
    sel = lambda name: kind == TRIPLET_KINDS.index(name)
    S = jp.Status
    assert np.all(np.isin(sol.status[sel("nan") | sel("inf")], [S.NOT_FINITE]))
    for name in ("collinear", "two_equal", "all_equal", "zero_area"):
        assert np.all(np.isin(sol.status[sel(name)], [S.DEGENERATE_IMAGE, S.DEGENERATE_MODEL]))
    assert np.all(sol.status[sel("near_collinear")] != S.OK)
    # Every valid root puts the three points in front of the camera.
    m = np.asarray(model, np.float64)
    rows = np.flatnonzero(~(sel("nan") | sel("inf")))
    for k in range(4):
        R_k, t_k = sol.R[rows, k].astype(np.float64), sol.t[rows, k].astype(np.float64)
        front = _front(np.asarray(C)[rows], R_k, t_k, m[rows], np.ones((rows.size, 3), bool))
        assert np.all(front[sol.valid[rows, k]])
    # Valid triplets: the true pose is among the roots.
    good = sel("valid") | sel("huge") | sel("tiny")
    err = np.min(np.where(sol.valid, _angle(sol.R, R[:, None]), np.inf), axis=1)  # (B,) best root
    limit = 1e-6 if dtype == "float64" else 1e-2
    solved = good & (sol.status == S.OK)
    assert np.mean(solved[good]) > 0.95  # the rest: image triangles below 40 px^2
    rate = np.mean(err[solved] < limit)
    assert rate >= (1.0 if dtype == "float64" else 0.99), (
        rate,
        np.flatnonzero(solved & (err >= limit)),
    )
    # p3p in the camera frame: the rotation of a valid problem is among the roots.
    pgood = ~(sel("nan") | sel("collinear") | sel("two_equal") | sel("all_equal"))
    pgood &= ~(sel("near_collinear") | sel("zero_area") | sel("behind") | sel("inf"))
    perr = np.min(np.where(pvalid, _angle(pR, R_cam[:, None]), np.inf), axis=1)
    assert np.mean(perr[pgood] < limit) >= (1.0 if dtype == "float64" else 0.99)
    assert not np.any(pvalid[sel("nan")])


# --------------------------------------------------------------------------- linear, LM


def _poison(rng, s, rows):
    """Put a NaN or an inf (either sign) into the camera, or into an active (unmasked)
    model or image point, of each of `rows` (problems with at least one active match)."""
    for b in rows:
        name = ("camera", "model", "image")[rng.integers(0, 3)]
        arr = s[name]
        if name == "camera":
            index = (b, rng.integers(0, 3), rng.integers(0, 4))
        else:
            index = (b, rng.choice(np.flatnonzero(s["mask"][b])), rng.integers(0, arr.shape[2]))
        arr[index] = rng.choice([np.nan, np.inf, -np.inf])


def _perturbed(rng, R, t, scale, angle):
    """The pose `(R, t)` moved by `angle` rad about a random axis and `angle` of the scene
    size (about 6 `scale`) along a random direction."""
    B = len(R)
    axis = _unit(rng, B)
    K = np.einsum("ijk,bk->bij", _LEVI_CIVITA, axis)
    a = angle[:, None, None]
    Rd = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
    return Rd @ R, t + 6 * scale[:, None] * angle[:, None] * _unit(rng, B)


_LEVI_CIVITA = np.zeros((3, 3, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI_CIVITA[_i, _j, _k], _LEVI_CIVITA[_i, _k, _j] = -1.0, 1.0


@jax.jit
def _linear_group(C, model, image, mask, R0, t0):
    obs = jax.vmap(jp.observations)(C, model, image, mask)
    return jax.vmap(lambda o, R, t: jp.solvers.linear(o, jp.Pose(R, t)))(obs, R0, t0)


@jax.jit
def _nonlinear_group(C, model, image, mask, R0, t0):
    obs = jax.vmap(jp.observations)(C, model, image, mask)
    return jax.vmap(lambda o, R, t: jp.solvers.nonlinear(o, jp.Pose(R, t)))(obs, R0, t0)


REFINERS = [("linear", LINEAR_BATCH), ("nonlinear", NONLINEAR_BATCH)]


def _refine(method, batch, poison):
    """`linear` / `nonlinear` from near the truth (80%) or anywhere (20%), on `scenes`;
    with `poison`, a tenth of the problems get a NaN or an inf."""
    rng = np.random.default_rng(40)
    s = scenes(
        rng, batch, kinds=rng.choice([k for k in range(len(KINDS)) if k != KIND["too_few"]], batch)
    )
    poisoned = (rng.random(batch) < 0.1) & poison
    _poison(rng, s, np.flatnonzero(poisoned))
    angle = np.where(rng.random(batch) < 0.8, 0.02, rng.uniform(0, np.pi, batch))
    R0, t0 = _perturbed(rng, s["R"], s["t"], s["scale"], angle)
    run = _linear_group if method == "linear" else _nonlinear_group
    out = jax.tree.map(np.asarray, run(s["camera"], s["model"], s["image"], s["mask"], R0, t0))
    return s, out, poisoned, angle


@pytest.mark.parametrize(("method", "batch"), REFINERS)
def test_linear_and_nonlinear(method, batch):
    s, out, _, angle = _refine(method, batch, poison=False)
    assert _finite(out.pose, out.error)
    assert set(np.unique(out.status)) <= VALID_STATUSES
    S = jp.Status
    good = np.isin(s["kind"], [KIND[k] for k in GOOD_KINDS]) & (angle == 0.02)
    if method == "linear":  # nonlinear: see test_nonlinear_converges_on_exact_data
        assert np.all(out.status[good] == S.OK)
    assert np.max(out.error[good]) < 1e-9
    assert np.max(_angle(out.pose.R[good], s["R"][good])) < 1e-9
    t_err = np.linalg.norm(out.pose.t - s["t"], axis=1) / s["scale"]
    assert np.max(t_err[good]) < 1e-8
    converged = out.status == S.OK
    assert np.all(_front(s["camera"], out.pose.R, out.pose.t, s["model"], s["mask"])[converged])


def test_nonlinear_converges_on_exact_data():
    s, out, _, angle = _refine("nonlinear", NONLINEAR_BATCH, poison=False)
    good = np.isin(s["kind"], [KIND[k] for k in GOOD_KINDS]) & (angle == 0.02)
    assert np.max(_angle(out.pose.R[good], s["R"][good])) < 1e-9  # the pose is exact
    assert np.all(out.status[good] == jp.Status.OK)


@pytest.mark.parametrize(("method", "batch"), REFINERS)
def test_linear_and_nonlinear_non_finite(method, batch):
    s, out, poisoned, _ = _refine(method, batch, poison=True)
    assert _finite(out.pose, out.error)
    assert np.all(out.status[poisoned] == jp.Status.NOT_FINITE)


# --------------------------------------------------------------------------- solve

# The batch-first path (one camera per problem); `test_vmapped_solve_equals_solve_many`
# checks `jax.vmap(solve)` against it on the first `VMAP_BATCH` problems.
_solve = jax.jit(jp.solve_many)
_is_success = jax.jit(jp.Status.is_success)
REJECTED_KINDS = ("collinear", "near_collinear", "duplicated", "zero_area", "too_few")


# Kinds of generated problem that `solve` reports as degenerate (see `test_solve`).
DEGENERATE_SOLVE_KINDS = ("collinear", "near_collinear", "duplicated", "zero_area")


def _check_solutions(out, s, dtype):
    """Properties every answer of `solve` has, whatever its input."""
    assert _finite(out.pose, out.error, out.pose_error)
    assert set(np.unique(out.status)) <= VALID_STATUSES
    assert np.array_equal(out.accepted, np.asarray(_is_success(out.status)))
    assert out.triplet.shape[-1] == 3
    assert np.all((out.triplet >= 0) & (out.triplet < N_POINTS))
    assert np.max(_orthonormality(out.pose.R)) < 1e3 * EPS[dtype]


@functools.cache
def _solved(dtype):
    """`SOLVE_BATCH[dtype]` generated problems through `jaxpose.solve_many` (once)."""
    rng = np.random.default_rng(50 + DTYPES.index(dtype))
    s = scenes(rng, SOLVE_BATCH[dtype])
    args = [np.asarray(s[k], dtype) for k in ("camera", "model", "image")]
    out = jax.tree.map(np.asarray, _solve(*args, s["mask"]))
    return s, args, out


def _exact_problems(s):
    """Valid noise-free problems with 4 to 6 matches: one pose explains them."""
    active = s["mask"].sum(axis=1)
    few = s["kind"] == KIND["few"]
    return np.isin(s["kind"], [KIND[k] for k in GOOD_KINDS]) | (few & (active == 4))


@pytest.mark.parametrize("dtype", DTYPES)
def test_solve(dtype):
    from helpers import opencv_optimum

    s, args, out = _solved(dtype)
    _check_solutions(out, s, dtype)
    kind, S = s["kind"], jp.Status
    is_kind = lambda *names: np.isin(kind, [KIND[k] for k in names])
    R, t = out.pose.R.astype(np.float64), out.pose.t.astype(np.float64)
    C, m = np.asarray(args[0], np.float64), np.asarray(args[1], np.float64)
    # Accepted poses never put a point behind the camera.
    assert np.all(_front(C, R, t, m, s["mask"])[out.accepted])
    # Degenerate problems: not accepted, and the status says why.
    assert not np.any(out.accepted[is_kind(*REJECTED_KINDS)])
    deg = is_kind(*DEGENERATE_SOLVE_KINDS)
    assert np.all(np.isin(out.status[deg], [S.DEGENERATE_IMAGE, S.DEGENERATE_MODEL]))
    assert np.all(out.status[is_kind("too_few")] == S.TOO_FEW_POINTS)
    # Valid noise-free problems, 4 to 6 matches: the true pose when accepted (every one of
    # them should be: see test_solve_accepts_every_exact_problem).
    active = s["mask"].sum(axis=1)
    exact = _exact_problems(s)
    assert np.mean(out.accepted[exact]) > 0.99
    good = exact & out.accepted
    tol = 1e-9 if dtype == "float64" else 1e-4
    assert np.max(_angle(R[good], s["R"][good])) < tol
    assert np.max((np.linalg.norm(t - s["t"], axis=1) / s["scale"])[good]) < 10 * tol
    # Three matches: an exact pose (one of up to four) whenever one is accepted.
    three = is_kind("few") & (active == 3) & out.accepted
    assert np.max(out.error[three], initial=0) < (1e-6 if dtype == "float64" else 1e-2)
    # Noisy problems: OpenCV's float64 optimum (SQPnP + LM), or a lower Eq. 8 error.
    noisy = np.flatnonzero(is_kind("noisy"))
    assert np.all(out.accepted[noisy])
    for b in noisy[:100]:
        scene = type("S", (), dict(camera=C[b], model_points=m[b], image_points=s["image"][b]))
        R_cv, t_cv = opencv_optimum(scene)
        e_cv = _eq8(C[b : b + 1], R_cv[None], t_cv[None], m[b : b + 1], s["image"][b : b + 1])[0]
        e_jp = _eq8(C[b : b + 1], R[b : b + 1], t[b : b + 1], m[b : b + 1], s["image"][b : b + 1])[
            0
        ]
        if dtype == "float64":
            assert e_jp <= e_cv * (1 + 1e-9) + 1e-12, (b, e_jp, e_cv)
            if e_jp >= e_cv * (1 - 1e-9):
                assert _angle(R[b], R_cv) < 1e-6, b
                assert np.linalg.norm(t[b] - t_cv) < 1e-6 * (1 + np.linalg.norm(t_cv)), b
        else:
            assert e_jp <= e_cv + 1e-3, (b, e_jp, e_cv)


def test_vmapped_solve_equals_solve_many():
    """`jax.vmap(solve)` (each problem its own mixed algorithm) gives the batch-first
    path's answers on hostile input too; and `solve` is jit-, vmap- and grad-friendly
    there: one compiled `jit(vmap(grad))` gives both the answers and the gradient of each
    translation with respect to the pixels, finite wherever the input is."""

    def loss(camera, model, image, mask):
        sol = jp.solve(camera, model, image, mask)
        return jnp.sum(sol.pose.t), sol

    s, args, many = _solved("float64")
    rows = slice(0, VMAP_BATCH)
    inputs = [a[rows] for a in args]
    grad, one = jax.jit(jax.vmap(jax.grad(loss, argnums=2, has_aux=True)))(*inputs, s["mask"][rows])
    one, grad = jax.tree.map(np.asarray, one), np.asarray(grad)
    finite = np.all([np.isfinite(np.asarray(a)).reshape(len(a), -1).all(1) for a in inputs], 0)
    assert grad.shape == (VMAP_BATCH, N_POINTS, 2)
    assert np.all(np.isfinite(grad[finite]))
    # an accepted pose moves with its pixels (those of the used matches)
    assert all(np.any(grad[b] != 0) for b in np.flatnonzero(one.accepted))
    many = jax.tree.map(lambda x: x[rows], many)
    _check_solutions(one, jax.tree.map(lambda x: x[rows], s), "float64")
    # Degenerate problems (points on a line, repeated or of no area): not accepted, and
    # the status says why, one problem at a time as in the batch.
    deg = np.isin(s["kind"][rows], [KIND[k] for k in DEGENERATE_SOLVE_KINDS])
    assert np.count_nonzero(deg) >= 8
    assert not np.any(one.accepted[deg])
    S = jp.Status
    assert np.all(np.isin(one.status[deg], [S.DEGENERATE_IMAGE, S.DEGENERATE_MODEL]))
    np.testing.assert_array_equal(one.accepted, many.accepted)
    # The same reason for every failure; an exact fit may be accepted at step 2 by one and
    # step 4 by the other (its error is rounding either way).
    np.testing.assert_array_equal(one.status[~one.accepted], many.status[~many.accepted])
    np.testing.assert_allclose(one.error, many.error, rtol=1e-9, atol=1e-12)
    # The same pose wherever the matches determine one (not three points seen twice).
    sure = np.isin(s["kind"][rows], [KIND[k] for k in GOOD_KINDS + ("noisy",)])
    np.testing.assert_allclose(one.pose.R[sure], many.pose.R[sure], atol=1e-9)
    scale = 1 + np.linalg.norm(many.pose.t[sure], axis=1, keepdims=True)
    np.testing.assert_allclose(one.pose.t[sure] / scale, many.pose.t[sure] / scale, atol=1e-9)


@pytest.mark.parametrize("dtype", DTYPES)
def test_solve_accepts_every_exact_problem(dtype):
    s, _, out = _solved(dtype)
    exact = _exact_problems(s)
    missed = np.flatnonzero(exact & ~out.accepted)
    assert missed.size == 0, [(b, KINDS[s["kind"][b]], int(out.status[b])) for b in missed]


def _solve_terminates_on_non_finite() -> bool:
    """Whether the mixed algorithm's buffered loop returns when a triplet that needs
    Levenberg-Marquardt has a non-finite error (a cheap probe in a subprocess; hostile input
    used to spin it forever). An import error means the code changed: assume it does."""
    probe = textwrap.dedent(
        """
        import jax, jax.numpy as jnp
        jax.config.update("jax_enable_x64", True)
        try:
            from jaxpose.strategy._jobs import Jobs, run_jobs
        except ImportError:
            raise SystemExit(0)
        need = jnp.array([False, False, True])
        for p in (jnp.finfo(jnp.float64).max, jnp.inf, jnp.nan):
            jobs = Jobs(need, jnp.array([0.0, 0.0, p]), (jnp.arange(3.0),),
                        (jnp.zeros(3),), jnp.zeros(3, bool))
            jax.block_until_ready(run_jobs(
                lambda x: (2 * x,), jobs, 1, 1, lambda phase, jobs, carry: (jobs, carry), 0))
        """
    )
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    try:
        subprocess.run([sys.executable, "-c", probe], env=env, timeout=30, check=True)
    except subprocess.TimeoutExpired:
        return False
    return True


def test_solve_non_finite():
    """NaN and inf in the camera, the model or the image: finite placeholders, not
    accepted, status `NOT_FINITE` (the first failing problem is printed)."""
    assert _solve_terminates_on_non_finite()
    dtype = "float64"
    B = SOLVE_BATCH[dtype]  # the shape test_solve compiled
    rng = np.random.default_rng(60)
    s = scenes(rng, B, kinds=rng.choice([KIND[k] for k in GOOD_KINDS + ("noisy",)], B))
    poisoned = np.arange(B) < NON_FINITE_BATCH
    _poison(rng, s, np.flatnonzero(poisoned))
    out = jax.tree.map(np.asarray, _solve(s["camera"], s["model"], s["image"], s["mask"]))
    finite = np.all(np.isfinite(out.pose.t), axis=1) & np.isfinite(out.pose_error)
    first = np.flatnonzero(poisoned & ~finite)[:1]
    for b in first:
        print("non-finite output for", {k: s[k][b].tolist() for k in ("camera", "model", "image")})
    _check_solutions(out, s, dtype)
    assert not np.any(out.accepted[poisoned])
    assert np.all(out.status[poisoned] == jp.Status.NOT_FINITE)


# --------------------------------------------------------------------------- solve_pnp_batch


def _pnp_batch():
    """`solve_pnp_batch(method="three_point")` on `PNP_BATCH` problems of OpenCV's form
    (one `K`, world = camera frame); returns the scenes, the camera-frame truth, and the
    answers."""
    rng = np.random.default_rng(70)
    kinds = [KIND[k] for k in KINDS if k not in ("few", "too_few", "huge", "tiny")]
    s = scenes(rng, PNP_BATCH, kinds=rng.choice(kinds, PNP_BATCH))
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    # Re-express every problem in its camera frame, seen by K.
    pc = np.einsum("bij,bnj->bni", s["R_wc"], _world(s)) + s["t_wc"][:, None]
    h = pc @ K.T
    image = h[..., :2] / h[..., 2:]
    noisy = s["kind"] == KIND["noisy"]
    image[noisy] += rng.normal(size=image[noisy].shape)
    ok, rvecs, tvecs = jp.solve_pnp_batch(s["model"], image, K, method="three_point")
    R_cam = s["R_wc"] @ s["R"]
    t_cam = np.einsum("bij,bj->bi", s["R_wc"], s["t"]) + s["t_wc"]
    R_out = np.stack([cv2.Rodrigues(r)[0] for r in rvecs])
    camera = np.broadcast_to(np.hstack([K, np.zeros((3, 1))]), (PNP_BATCH, 3, 4))
    front = _front(camera, R_out, tvecs, s["model"], np.ones(s["mask"].shape, bool))
    return s, (R_cam, t_cam), (ok, rvecs, tvecs, R_out), front


def test_solve_pnp_batch_degenerate_and_valid():
    """OpenCV's conventions, the three-point method (cheap to compile): degenerate
    problems come back `ok=False` and finite, valid ones exact."""
    s, (R_cam, t_cam), (ok, rvecs, tvecs, R_out), front = _pnp_batch()
    assert ok.shape == (PNP_BATCH,) and rvecs.shape == tvecs.shape == (PNP_BATCH, 3)
    assert _finite(rvecs, tvecs)
    is_kind = lambda *names: np.isin(s["kind"], [KIND[k] for k in names])
    assert not np.any(ok[is_kind("collinear", "near_collinear", "duplicated", "zero_area")])
    good = is_kind("valid", "planar")
    assert np.all(ok[good])
    assert np.max(_angle(R_out[good], R_cam[good])) < 1e-9
    assert np.max(np.linalg.norm(tvecs - t_cam, axis=1)[good]) < 1e-8
    assert np.all(front[ok & ~is_kind("some_behind")])


def test_solve_pnp_batch_three_point_keeps_points_in_front():
    s, _, (ok, *_), front = _pnp_batch()
    assert np.all(front[ok])


def _world(s):
    return np.einsum("bij,bnj->bni", s["R"], s["model"]) + s["t"][:, None]


# --------------------------------------------------------------------------- validation

_OBJ = np.random.default_rng(0).normal(size=(6, 3))
_IMG = np.random.default_rng(1).uniform(0, 600, size=(6, 2))
_K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])


@st.composite
def _bad_points(draw, dim, n=6):
    """An array-like that is not `(n, dim)` points (or OpenCV's layouts of them)."""
    kind = draw(
        st.sampled_from(["last_dim", "ndim", "few", "nan", "dtype", "ragged", "none", "count"])
    )
    base = np.random.default_rng(draw(st.integers(0, 99))).normal(size=(n, dim)) * 100
    if kind == "last_dim":
        return np.zeros((n, draw(st.sampled_from([d for d in range(0, 6) if d != dim]))))
    if kind == "ndim":
        return draw(st.sampled_from([base.ravel(), np.stack([base, base]), base[None, None], 3.0]))
    if kind == "few":
        return base[: draw(st.integers(0, 2))]
    if kind == "nan":
        base[draw(st.integers(0, n - 1)), draw(st.integers(0, dim - 1))] = draw(
            st.sampled_from([np.nan, np.inf, -np.inf])
        )
        return base
    if kind == "dtype":
        return draw(
            st.sampled_from(
                [base.astype(complex), base > 0, base.astype(str), np.full((n, dim), None)]
            )
        )
    if kind == "ragged":
        return [list(row) for row in base[:-1]] + [list(base[-1, :-1])]
    if kind == "none":
        return None
    count = draw(st.sampled_from([3, 4, 5, n + 1]))  # not the other argument's count
    return np.vstack([base, base])[:count]


@st.composite
def _bad_intrinsics(draw):
    K = _K.copy()
    kind = draw(st.sampled_from(["shape", "nan", "focal", "lower", "k22", "singular", "dtype"]))
    if kind == "shape":
        return draw(st.sampled_from([np.hstack([K, np.zeros((3, 1))]), K[:2, :2], K.ravel()]))
    if kind == "nan":
        K[draw(st.integers(0, 2)), draw(st.integers(0, 2))] = draw(
            st.sampled_from([np.nan, np.inf])
        )
    elif kind == "focal":
        K[draw(st.sampled_from([(0, 0), (1, 1)]))] = draw(st.sampled_from([0.0, -800.0]))
    elif kind == "lower":
        K[draw(st.sampled_from([(1, 0), (2, 0), (2, 1)]))] = draw(st.floats(1, 1e3))
    elif kind == "k22":
        K[2, 2] = 0
    elif kind == "singular":
        K[0, 0] = K[1, 1] = 1e-20
    else:
        return K.astype(complex)
    return K


# Bad values of the arguments that the OpenCV-style and batch entry points share, by name.
_BAD_OPTIONS = {
    "camera_matrix": _bad_intrinsics(),
    "dist_coeffs": st.sampled_from(
        [np.zeros(3), np.ones(6), np.ones((2, 5)), np.array([0.1, np.nan, 0, 0]), np.ones(4) * 1j]
    ),
    "triplet_budget": st.sampled_from([0, -3, 1.5, True, "8"]),
    "chunk_size": st.sampled_from([0, -1, 2.5, True, "64"]),
    "devices": st.sampled_from([0, -1, 10**6, "cpu", [], [1, 2], 1.5]),
}


@settings(max_examples=HYPOTHESIS_EXAMPLES)
@given(data=st.data())
def test_solve_pnp_rejects_bad_arguments(data):
    pnp_options = ("camera_matrix", "dist_coeffs", "triplet_budget")
    which = data.draw(st.sampled_from(["object_points", "image_points", "method", *pnp_options]))
    args = dict(object_points=_OBJ, image_points=_IMG, camera_matrix=_K)
    if which in ("object_points", "image_points"):
        args[which] = data.draw(_bad_points(3 if which == "object_points" else 2))
    elif which == "method":
        args[which] = data.draw(st.sampled_from(["", "MIXED", "sqpnp", "p3p"]))
    else:
        args[which] = data.draw(_BAD_OPTIONS[which])
    with pytest.raises(ValueError, match=which):
        jp.solve_pnp(**args)


@settings(max_examples=HYPOTHESIS_EXAMPLES)
@given(data=st.data())
def test_solve_pnp_batch_rejects_bad_arguments(data):
    B = 4
    obj, img = np.stack([_OBJ] * B), np.stack([_IMG] * B)
    which = data.draw(st.sampled_from(["object_points", "image_points", *_BAD_OPTIONS, "batch"]))
    args = dict(object_points=obj, image_points=img, camera_matrix=_K)
    if which == "object_points":
        bad = data.draw(_bad_points(3).filter(lambda x: not isinstance(x, list)))  # see below
        args[which] = data.draw(
            st.sampled_from(
                [bad, np.stack([obj[0]] * (B + 1)), np.zeros((B, 6, 4)), obj[..., None]]
            )
        )
    elif which == "image_points":
        args[which] = data.draw(
            st.sampled_from(
                [img[0], img[..., :1], np.zeros((B, 2, 2)), img.astype(complex), img.ravel()]
            )
        )
    elif which == "batch":  # NaN in one problem: the numpy boundary names the argument
        name = data.draw(st.sampled_from(["object_points", "image_points"]))
        arr = args[name].copy()
        arr[data.draw(st.integers(0, B - 1)), data.draw(st.integers(0, 5)), 0] = np.nan
        args[name] = arr
        which = name
    else:
        args[which] = data.draw(_BAD_OPTIONS[which])
    with pytest.raises(ValueError, match=which):
        jp.solve_pnp_batch(**args)


@settings(max_examples=HYPOTHESIS_EXAMPLES)
@given(data=st.data())
def test_solve_batch_rejects_bad_arguments(data):
    B = 4
    camera = np.hstack([_K, np.zeros((3, 1))])
    args = dict(camera=camera, models=np.stack([_OBJ] * B), images=np.stack([_IMG] * B))
    which = data.draw(
        st.sampled_from(
            [
                "camera",
                "models",
                "images",
                "masks",
                "method",
                "triplet_budget",
                "chunk_size",
                "devices",
            ]
        )
    )
    if which == "camera":
        args[which] = data.draw(
            st.sampled_from(
                [_K, np.stack([camera] * (B + 1)), camera.astype(complex), camera[None, None], None]
            )
        )
    elif which == "models":
        args[which] = data.draw(
            st.sampled_from(
                [np.zeros((B, 7, 3)), np.zeros((B + 1, 6, 3)), np.zeros((6, 2)), _OBJ > 0, None]
            )
        )
    elif which == "images":
        args[which] = data.draw(
            st.sampled_from(
                [_IMG, np.zeros((B, 2, 2)), np.zeros((0, 6, 2)), np.zeros((B, 6, 3)), "x"]
            )
        )
    elif which == "masks":
        args[which] = data.draw(
            st.sampled_from([np.ones((B, 6)), np.ones((B, 5), bool), np.ones(6, bool)])
        )
    elif which == "method":
        args[which] = "bad"
    else:
        args[which] = data.draw(_BAD_OPTIONS[which])
    with pytest.raises(ValueError, match=which):
        jp.solve_batch(**args)


@pytest.mark.parametrize(
    ("which", "value"),
    [
        ("object_points", [list(_OBJ[0])] * 5 + [list(_OBJ[0, :2])]),
        ("image_points", [[list(_IMG[0])] * 6, [list(_IMG[0])] * 5]),
        ("image_points", np.zeros((0, 6, 2))),
    ],
)
def test_solve_pnp_batch_names_ragged_and_empty_arguments(which, value):
    args = dict(object_points=_OBJ, image_points=np.stack([_IMG] * 2), camera_matrix=_K)
    args[which] = value
    with pytest.raises(ValueError, match=which):
        jp.solve_pnp_batch(**args)


_CAMERA = np.hstack([_K, np.zeros((3, 1))]) + np.array([0, 0, 0, 5.0])


@st.composite
def _bad_problem(draw):
    """One JAX-native problem with exactly one bad argument, and that argument's name."""
    args = dict(camera=_CAMERA, model=_OBJ, image=_IMG, mask=None)
    which = draw(st.sampled_from(["camera", "model", "image", "mask"]))
    options = {
        "camera": [
            _K,
            np.vstack([_CAMERA, _CAMERA[:1]]),
            _CAMERA.ravel(),
            _CAMERA.astype(complex),
            _CAMERA > 0,
        ],
        "model": [_OBJ[:, :2], _OBJ.ravel(), np.zeros((6, 4)), _OBJ.astype(complex)],
        "image": [np.hstack([_IMG, _IMG[:, :1]]), _IMG[:5], _IMG[:, None], _IMG > 0],
        "mask": [np.ones(5, bool), np.ones(6), np.ones((6, 1), bool)],
    }[which]
    args[which] = draw(st.sampled_from(options))
    if which == "model" and draw(st.booleans()):  # too few matches, on both sides
        args["model"], args["image"], which = _OBJ[:2], _IMG[:2], "model and image"
    return args, which


@settings(max_examples=HYPOTHESIS_EXAMPLES)
@given(case=_bad_problem())
def test_check_problem_rejects_bad_arguments(case):
    args, which = case
    with pytest.raises(ValueError, match=which):
        check_problem(**args)
    with pytest.raises(ValueError, match=which):  # at trace time, under jit and vmap
        jax.eval_shape(lambda *a: check_problem(*a), *args.values())


@pytest.mark.parametrize(
    ("which", "value"),
    [
        ("camera", _K),
        ("camera", np.vstack([_CAMERA, _CAMERA[:1]])),
        ("model", _OBJ[:, :2]),
        ("image", _IMG[:5]),
        ("mask", np.ones(5, bool)),
        ("model and image", None),
    ],
)
def test_solve_rejects_bad_shapes(which, value):
    args = dict(camera=_CAMERA, model=_OBJ, image=_IMG, mask=None)
    if value is None:
        args["model"], args["image"] = _OBJ[:2], _IMG[:2]
    else:
        args[which] = value
    with pytest.raises(ValueError, match=which):
        jax.eval_shape(lambda: jp.solve(**args, method="three_point"))


@pytest.mark.parametrize("total", [TOTAL_CASES], ids=[f"{TOTAL_CASES}_cases"])
def test_case_count(total):
    assert total >= 10**5
    print(f"fuzz suite: {total} generated cases", {k: v for k, v in CASES.items()})
