"""float32 against float64: how far jaxpose's answers move when it computes in float32.

**Protocol:** the standard synthetic PnP protocol of `benchmarks/accuracy.py`
(`benchmarks/_protocol.py`, its `make_cell`: `f = 800`, 640x480 image with a centred
principal point, OpenCV's convention; camera-frame points uniform in
`[-2,2]x[-2,2]x[4,8]` "ordinary", `[1,2]x[1,2]x[4,8]` "quasi_singular", or on a plane
`[-2,2]^2` tilted by up to 30 degrees at depth 4-8 "planar"), `n` in (4, 6, 10, 20, 50),
pixel noise `sigma` in (0, 0.5, 2) px. Every cell's seeded trials are solved twice by the
mixed method with its default settings:

- float64: `jaxpose.solve_pnp_batch` (x64 enabled by this script), in the same
  fixed-size chunks as `benchmarks/accuracy.py`;
- float32: the same computation, `jax.jit` of
  `jaxpose.solve_many(jaxpose.geometry.camera_matrix(K), obj, img, method=...)`, the
  function `solve_pnp_batch` compiles, fed float32 arrays (`solve_pnp_batch` itself
  always casts to float64; `solve_many` keeps its inputs' dtype, so this is the
  library's float32 path).

**Per cell** (over the trials where both are accepted unless said otherwise; float32
rotations are first taken to the nearest rotation in float64, as a rotation vector would
be, and their orthonormality defect `max |R32^T R32 - I|` is reported apart):
- `rotation_diff_deg`: the angle of `R32^T R64` (median, 99th percentile, max);
- `translation_rel_diff`: `|t32 - t64| / |t64|` (same statistics);
- `rms_diff_px`: Eq. 8 reprojection RMS of the float32 pose minus that of the float64
  pose, both evaluated in float64 on the original (unrounded) data (same statistics;
  positive means float32 is worse);
- `at_float64_optimum`: the share of the trials accepted in float64 where float32 is
  accepted too and its RMS is within `RMS_TOL` = 1e-3 px of float64's. Why 1e-3 px:
  float32's own floor, the float64 pose rounded to float32 (`rounding_floor_px`, also
  reported per cell), costs up to ~3e-5 px, float32 pixel coordinates are spaced
  3e-5-6e-5 px apart in a 640x480 image, and converged float32 answers measure within
  ~6e-5 px of float64's; 1e-3 px is more than ten times all three and far below what a
  different local minimum or an unrefined triplet pose costs (0.1 px and more), and
  below the 0.5-2 px noise of the noisy cells by three orders of magnitude;
- `float32_failed_float64_ok`: the share of all trials where float32 returns `ok=False`
  while float64 returns `ok=True` (and `float64_failed_float32_ok`, the reverse);
- the median rotation error of each against the true pose, for scale.

**P3P alone:** `benchmarks/p3p_rate.py`'s protocol (2e4 random noise-free instances; 2e3
with `--quick`) run here in float32 and float64 without peers: found-the-true-pose rates
at 1e-6 and 1e-3 and error quantiles. The stored `benchmarks/results/p3p_rate_float32.json`
(from an earlier solver) is quoted beside them when present.

    python benchmarks/float32.py            # full (see `default_trials`)
    python benchmarks/float32.py --quick    # a few trials per cell

Prints a table and writes `benchmarks/results/float32.json` (`float32_quick.json`).
`main(argv)` returns the result dict.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/float32.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from benchmarks import _protocol as protocol
from benchmarks import p3p_rate
from benchmarks._harness import RESULTS, Stopwatch, compilation_cache, versions, write_json

KINDS = protocol.KINDS
NS = (4, 6, 10, 20, 50)
SIGMAS = (0.0, 0.5, 2.0)
RMS_TOL = 1e-3  # px: "at the float64 optimum" (see the module docstring)


def default_trials(quick: bool) -> dict[int, int]:
    """Trials per cell by `n`: the full run keeps the solving under ~5 minutes on a
    2-core CPU (float64 and float32 together; the n = 50 problems cost ~0.4 s each),
    on top of compiling ten programs (one per `n` and dtype)."""
    if quick:
        return {4: 20, 6: 20, 10: 20, 20: 10, 50: 4}
    return {4: 200, 6: 200, 10: 200, 20: 50, 50: 20}  # multiples of accuracy's chunks


def _float32_solver(method: str):
    @jax.jit
    def solve(K, obj, img):
        sol = jp.solve_many(jp.geometry.camera_matrix(K), obj, img, method=method)
        return sol.accepted, sol.pose.R, sol.pose.t

    return solve


def solve_float32(solver, cell: protocol.Cell, trials: int, chunk: int) -> protocol.Answers:
    """The float32 twin of `protocol.solve_jaxpose`: same padded chunks, float32 arrays."""
    R, t, ok = np.tile(np.eye(3), (trials, 1, 1)), np.zeros((trials, 3)), np.zeros(trials, bool)
    K = jnp.asarray(cell.K, jnp.float32)
    watch = Stopwatch()
    for s in range(0, trials, chunk):
        idx = np.minimum(np.arange(s, s + chunk), trials - 1)
        okb, Rb, tb = solver(
            K, jnp.asarray(cell.obj[idx], jnp.float32), jnp.asarray(cell.img[idx], jnp.float32)
        )
        assert Rb.dtype == jnp.float32, Rb.dtype
        m = min(chunk, trials - s)
        R[s : s + m] = np.asarray(Rb, np.float64)[:m]
        t[s : s + m] = np.asarray(tb, np.float64)[:m]
        ok[s : s + m] = np.asarray(okb)[:m]
    return protocol.Answers(R, t, ok, watch.seconds)


def _stats(x: np.ndarray) -> dict:
    """Median, 99th percentile and max (NaN when empty), as plain floats."""
    x = np.asarray(x, np.float64)
    if x.size == 0:
        return {"median": float("nan"), "p99": float("nan"), "max": float("nan")}
    return {
        "median": float(np.median(x)),
        "p99": float(np.quantile(x, 0.99)),
        "max": float(np.max(x)),
    }


def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation nearest to each `(3, 3)` matrix (polar factor, float64): a float32
    rotation is orthonormal to ~1e-7 only, and that defect, an affine freedom of its own,
    would otherwise show up as (tiny) rotation and reprojection differences."""
    U, _, Vt = np.linalg.svd(np.asarray(R, np.float64))
    D = np.ones(U.shape[:-1])
    D[..., -1] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt


def compare(cell: protocol.Cell, a64: protocol.Answers, a32: protocol.Answers) -> dict:
    """The per-cell figures of the module docstring (float32 rotations taken to the
    nearest rotation first; their orthonormality defect is reported apart)."""
    B = len(a64.ok)
    obj, img = cell.obj[:B], cell.img[:B]
    both = a64.ok & a32.ok
    R32 = nearest_rotation(a32.R)
    defect = np.abs(np.swapaxes(a32.R, -1, -2) @ a32.R - np.eye(3)).max(axis=(-2, -1))
    rms64 = protocol.reprojection_rms(obj, img, cell.K, a64.R, a64.t)
    rms32 = protocol.reprojection_rms(obj, img, cell.K, R32, a32.t)
    R_round = nearest_rotation(a64.R.astype(np.float32))
    t_round = a64.t.astype(np.float32).astype(np.float64)
    floor = protocol.reprojection_rms(obj, img, cell.K, R_round, t_round) - rms64
    rot = protocol.rotation_angle_deg(R32, a64.R)
    norm64 = np.linalg.norm(a64.t, axis=1)
    trel = np.linalg.norm(a32.t - a64.t, axis=1) / np.where(norm64 > 0, norm64, 1.0)
    drms = rms32 - rms64
    at_opt = both & (drms <= RMS_TOL)
    err64 = protocol.rotation_error_deg(cell.R[:B], a64.R)
    err32 = protocol.rotation_error_deg(cell.R[:B], R32)
    n64 = max(int(a64.ok.sum()), 1)
    return {
        "kind": cell.kind,
        "n": cell.n,
        "sigma": cell.sigma,
        "trials": B,
        "ok_float64": float(np.mean(a64.ok)),
        "ok_float32": float(np.mean(a32.ok)),
        "rotation_diff_deg": _stats(rot[both]),
        "translation_rel_diff": _stats(trel[both]),
        "rms_diff_px": _stats(drms[both]),
        "rounding_floor_px": _stats(floor[a64.ok]),
        "float32_orthonormality_defect": _stats(defect[a32.ok]),
        "at_float64_optimum": float(at_opt.sum() / n64),
        "float32_failed_float64_ok": float(np.mean(a64.ok & ~a32.ok)),
        "float64_failed_float32_ok": float(np.mean(a32.ok & ~a64.ok)),
        "median_rotation_error_deg": {
            "float64": float(np.median(err64[a64.ok])) if a64.ok.any() else float("nan"),
            "float32": float(np.median(err32[a32.ok])) if a32.ok.any() else float("nan"),
        },
        "seconds": {"float64": a64.seconds, "float32": a32.seconds},
    }


def p3p_figures(n: int, seed: int) -> dict:
    """`benchmarks/p3p_rate.py` in float32 and float64 (no peers), plus the stored file."""
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for dtype in ("float32", "float64"):
            out = Path(tmp) / f"{dtype}.json"
            res = p3p_rate.main(
                [
                    "--n",
                    str(n),
                    "--seed",
                    str(seed),
                    "--dtype",
                    dtype,
                    "--no-peers",
                    "--repeats",
                    "1",
                    "--out",
                    str(out),
                ]
            )
            rows.update(res["rows"])
    keep = (
        "found_rate",
        "found_rate_at_1e-3",
        "p999_error",
        "median_error",
        "max_error",
        "mean_solutions",
        "nonfinite_solutions",
    )
    out = {
        "instances": n,
        "seed": seed,
        "tol": 1e-6,
        "rows": {k: {f: v[f] for f in keep} for k, v in rows.items()},
    }
    stored = RESULTS / "p3p_rate_float32.json"
    if stored.exists():
        old = json.loads(stored.read_text())
        row = next(iter(old["rows"].values()))
        out["stored_p3p_rate_float32_json"] = {
            "instances": old["args"]["n"],
            "note": "measured before the symmetric-configuration fix of p3p.py",
            **{f: row[f] for f in keep},
        }
    return out


def run(
    quick: bool,
    out_dir: str | Path | None = None,
    *,
    kinds: Sequence[str] = KINDS,
    ns: Sequence[int] = NS,
    sigmas: Sequence[float] = SIGMAS,
    trials: int | None = None,
    method: str = "mixed",
    p3p_n: int | None = None,
    seed: int = 0,
    verbose: bool = True,
    threads: bool = True,
) -> dict:
    jax.config.update("jax_enable_x64", True)  # this script's own choice
    per_n = default_trials(quick)
    if p3p_n is None:
        p3p_n = 2000 if quick else 20000
    solver32 = _float32_solver(method)
    watch = Stopwatch()
    specs = []
    for n in ns:
        B = trials if trials is not None else per_n.get(n, 20)
        for kind in kinds:
            for sigma in sigmas:
                specs.append((protocol.make_cell(kind, n, sigma, B, seed), B))

    def say(dtype, cell, B):
        if verbose:
            print(
                f"  {dtype} {cell.kind:>14} n={cell.n:<3} sigma={cell.sigma:<4} trials={B:<4} "
                f"[{watch.seconds:.0f} s]",
                flush=True,
            )

    def sweep64():
        out = []
        for cell, B in specs:
            out.append(protocol.solve_jaxpose(cell, method, B, protocol.chunk_size(cell.n, method)))
            say("float64", cell, B)
        return out

    def sweep32():
        out = []
        for cell, B in specs:
            out.append(solve_float32(solver32, cell, B, protocol.chunk_size(cell.n, method)))
            say("float32", cell, B)
        return out

    if threads:
        # The two sweeps are independent: on a small shared CPU, compiling and solving
        # them side by side roughly halves the wall time (per-cell seconds then overlap).
        with ThreadPoolExecutor(max_workers=1) as pool:
            future = pool.submit(sweep64)
            answers32 = sweep32()
            answers64 = future.result()
    else:
        answers64, answers32 = sweep64(), sweep32()
    cells = [
        compare(cell, a64, a32)
        for (cell, _), a64, a32 in zip(specs, answers64, answers32, strict=True)
    ]
    result = {
        "protocol": {
            "kinds": list(kinds),
            "ns": list(ns),
            "sigmas": list(sigmas),
            "trials_per_n": {
                str(n): (trials if trials is not None else per_n.get(n, 20)) for n in ns
            },
            "method": method,
            "rms_tol_px": RMS_TOL,
            "seed": seed,
            "float64": "jaxpose.solve_pnp_batch (x64)",
            "float32": "jax.jit(jaxpose.solve_many) on float32 arrays",
        },
        "cells": cells,
        "summary": summary(cells),
        "p3p": p3p_figures(p3p_n, seed) if p3p_n != 0 else None,
        "seconds": watch.seconds,
        "quick": quick,
    }
    result["versions"] = versions()
    out = Path(out_dir) if out_dir is not None else RESULTS
    path = write_json(out / ("float32_quick.json" if quick else "float32.json"), result)
    result["path"] = str(path)
    if verbose:
        print_table(result)
        print(f"wrote {path}")
    return result


def summary(cells: list[dict]) -> dict:
    """Over all cells, weighted by trials."""
    w = np.array([c["trials"] for c in cells], float)
    ok64 = np.array([c["ok_float64"] for c in cells]) * w

    def worst(key, stat):
        vals = [c[key][stat] for c in cells if np.isfinite(c[key][stat])]
        return float(max(vals)) if vals else float("nan")

    return {
        "trials": int(w.sum()),
        "at_float64_optimum": float(
            np.sum([c["at_float64_optimum"] for c in cells] * ok64) / max(ok64.sum(), 1)
        ),
        "float32_failed_float64_ok": float(
            np.sum([c["float32_failed_float64_ok"] for c in cells] * w) / w.sum()
        ),
        "float64_failed_float32_ok": float(
            np.sum([c["float64_failed_float32_ok"] for c in cells] * w) / w.sum()
        ),
        "worst_rotation_diff_deg_p99": worst("rotation_diff_deg", "p99"),
        "worst_rotation_diff_deg_max": worst("rotation_diff_deg", "max"),
        "worst_translation_rel_diff_p99": worst("translation_rel_diff", "p99"),
        "worst_rms_diff_px_p99": worst("rms_diff_px", "p99"),
        "worst_rounding_floor_px_max": worst("rounding_floor_px", "max"),
        "worst_float32_orthonormality_defect_max": worst("float32_orthonormality_defect", "max"),
    }


def print_table(result: dict) -> None:
    head = (
        f"{'kind':>14} {'n':>3} {'sigma':>5} {'trials':>6} | {'rot diff deg med/p99/max':>26} | "
        f"{'rel t diff med/p99/max':>26} | {'dRMS px med/p99/max':>27} | "
        f"{'at opt':>7} {'32 fail':>7} {'64 fail':>7}"
    )
    print(head)
    print("-" * len(head))

    def trio(s, fmt="{:.1e}"):
        return "/".join(fmt.format(s[k]) for k in ("median", "p99", "max"))

    for c in result["cells"]:
        print(
            f"{c['kind']:>14} {c['n']:>3} {c['sigma']:>5} {c['trials']:>6} | "
            f"{trio(c['rotation_diff_deg']):>26} | {trio(c['translation_rel_diff']):>26} | "
            f"{trio(c['rms_diff_px'], '{:+.1e}'):>27} | "
            f"{100 * c['at_float64_optimum']:6.1f}% {100 * c['float32_failed_float64_ok']:6.1f}% "
            f"{100 * c['float64_failed_float32_ok']:6.1f}%"
        )
    s = result["summary"]
    print(
        f"all {s['trials']} trials: float32 at the float64 optimum (RMS within {RMS_TOL:g} px) "
        f"{100 * s['at_float64_optimum']:.2f}%; float32 ok=False where float64 ok=True "
        f"{100 * s['float32_failed_float64_ok']:.2f}% (reverse "
        f"{100 * s['float64_failed_float32_ok']:.2f}%); float64 pose rounded to float32 "
        f"costs at most {s['worst_rounding_floor_px_max']:.1e} px"
    )
    p = result["p3p"]
    if p is None:
        return
    print(f"P3P alone, {p['instances']} random noise-free instances (found = error < 1e-6):")
    for name, r in p["rows"].items():
        print(
            f"  {name:<24} found {100 * r['found_rate']:.2f}%  found@1e-3 "
            f"{100 * r['found_rate_at_1e-3']:.2f}%  median err {r['median_error']:.1e}  "
            f"p99.9 err {r['p999_error']:.1e}"
        )
    if "stored_p3p_rate_float32_json" in p:
        r = p["stored_p3p_rate_float32_json"]
        print(
            f"  {'(stored, before the fix)':<24} found {100 * r['found_rate']:.2f}%  found@1e-3 "
            f"{100 * r['found_rate_at_1e-3']:.2f}%  median err {r['median_error']:.1e}"
        )


def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a few trials per cell")
    parser.add_argument("--trials", type=int, default=None, help="trials per cell (all n)")
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    parser.add_argument("--ns", nargs="+", type=int, default=list(NS))
    parser.add_argument("--sigmas", nargs="+", type=float, default=list(SIGMAS))
    parser.add_argument("--method", default="mixed", help="jaxpose method (default mixed)")
    parser.add_argument(
        "--p3p-n", type=int, default=None, help="P3P instances (default 2e4, quick 2e3; 0: skip)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--serial",
        dest="threads",
        action="store_false",
        help="float64 then float32 (default: side by side)",
    )
    parser.add_argument(
        "--out",
        dest="out_dir",
        metavar="OUT",
        default=None,
        help="output folder (default benchmarks/results)",
    )
    args = parser.parse_args(argv)
    if args.trials is not None and args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    compilation_cache()
    return run(**vars(args))  # every option is named after its keyword of `run`


if __name__ == "__main__":
    main()
