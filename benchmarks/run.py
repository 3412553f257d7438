"""The benchmark suite in one command: speed (`speed.py`) and accuracy (`accuracy.py`) of
jaxpose beside OpenCV and PoseLib, timed in the same run, and scaling (`scale.py`: time,
peak memory and compile time versus n and batch size).

    python benchmarks/run.py            # full (what the README's tables come from)
    python benchmarks/run.py --quick    # a few minutes
    python benchmarks/run.py --only speed
    python -m benchmarks.run --only scale

Prints the tables (with the targets and the ratio to each), writes
`benchmarks/results/speed.json` (and the accuracy module's JSON and plots),
`benchmarks/results/batch.png` and `scale.json` / `scale.png` (`*_quick.*` with
`--quick`). Computes in float64 (x64 enabled for this process and scale's workers).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/run.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax

from benchmarks._harness import (
    RESULTS,
    against,
    machine,
    rich_console,
    times_faster,
    write_json,
)


def print_speed(res: dict, console) -> None:
    from rich.table import Table

    T = res["targets"]
    p = res["paper"]
    lo = {"higher_is_better": False}
    hi = {"higher_is_better": True}
    t = Table(title=f"Paper protocol: all {p['triplets']} triplets of the default bench")
    for col in ("solver", "time", "jaxpose is", "target"):
        t.add_column(col, justify="right" if col != "solver" else "left")
    t.add_row(
        "jaxpose mixed (compiled call)",
        f"{p['jaxpose_ms']:.2f} ms",
        "",
        against(p["jaxpose_ms"], T["paper_ms"], **lo, unit=" ms"),
    )
    t.add_row(
        "OpenCV loop (solveP3P, best root, RefineLM)",
        f"{p['opencv_ms']:.1f} ms",
        times_faster(p["vs_opencv"]),
        against(p["vs_opencv"], T["paper_vs_opencv"], **hi, unit="x"),
    )
    t.add_row(
        "PoseLib loop (p3p, best root, refine)",
        f"{p['poselib_ms']:.1f} ms",
        times_faster(p["vs_poselib"]),
        against(p["vs_poselib"], T["paper_vs_poselib"], **hi, unit="x"),
    )
    console.print(t)
    ph = res.get("paper_phases")
    if ph:
        console.print(
            f"what it is made of (ms, each compiled alone): three-point roots "
            f"{ph['three_point_ms']:.2f}; step 1 (roots + Eq. 8 errors) {ph['step1_ms']:.2f}; "
            f"step 2 (linear from all {ph['triplets']}) {ph['step2_linear_ms']:.2f}; mixed "
            f"{ph['mixed_ms']:.2f}; solve (mixed + polish) {ph['solve_ms']:.2f}"
        )
    console.print(
        f"compile (cold, first call): {p['compile_s']:.1f} s "
        f"(target {against(p['compile_s'], T['compile_s'], **lo, unit=' s')})"
    )
    lat = res["latency"]
    console.print(
        f"single call solve_pnp (bench, exhaustive mixed): {lat['solve_pnp_ms']:.2f} ms "
        f"(target {against(lat['solve_pnp_ms'], T['latency_ms'], **lo, unit=' ms')}); "
        f"with triplet_budget=8: {lat['solve_pnp_budget8_ms']:.2f} ms; "
        f"cv2.solvePnP(SQPNP): {lat['cv2_sqpnp_us']:.0f} us"
    )
    b = Table(title="Batches: n = 16, 1 px, solve_pnp_batch(triplet_budget=8) vs OpenCV loop")
    for col in ("B", "jaxpose", "per problem", "OpenCV loop", "jaxpose is", "at optimum"):
        b.add_column(col, justify="right")
    for row in res["batch"]:
        b.add_row(
            str(row["B"]),
            f"{1e3 * row['jaxpose_s']:.1f} ms",
            f"{row['per_problem_us']:.0f} us",
            f"{1e3 * row['opencv_s']:.1f} ms",
            times_faster(row["vs_opencv"], 2),
            f"{100 * row['at_optimum']:.2f}%",
        )
    console.print(b)
    q = res["p3p"]
    la = res["linalg"]
    console.print(
        f"P3P alone: {q['ns_per_triplet']:.0f} ns per triplet amortised over {q['triplets']} "
        f"(target {against(q['ns_per_triplet'], T['p3p_ns_per_triplet'], **lo, unit=' ns')}). "
        f"6x6 normal equations: LAPACK {la['lapack_us_per_system']:.2f} us, unrolled "
        f"Cholesky {la['unrolled_us_per_system']:.3f} us per system ({la['ratio']:.0f}x)."
    )


def plot_batch(res: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = res["batch"]
    B = [r["B"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(B, [r["jaxpose_s"] for r in rows], "o-", label="jaxpose solve_pnp_batch")
    ax.loglog(B, [r["opencv_s"] for r in rows], "s--", label="OpenCV SQPnP + RefineLM loop")
    ax.set_xlabel("problems in the batch (n = 16)")
    ax.set_ylabel("time (s)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, smaller batches")
    parser.add_argument("--only", choices=("speed", "accuracy", "scale"), default=None)
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    from benchmarks import accuracy, scale, speed

    console = rich_console(120)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    info = machine()
    console.print(f"machine: {info['cpu']}, {info['cores']} cores, devices {info['devices']}")
    if args.only in (None, "speed"):
        with console.status("speed: compiling and timing..."):
            res = speed.run(quick=args.quick)
        res["machine"] = info
        res["quick"] = args.quick
        path = write_json(out / ("speed_quick.json" if args.quick else "speed.json"), res, indent=2)
        print_speed(res, console)
        plot_batch(res, out / ("batch_quick.png" if args.quick else "batch.png"))
        console.print(f"wrote {path}")
    if args.only in (None, "accuracy"):
        accuracy.run(quick=args.quick, out_dir=out)
    if args.only in (None, "scale"):
        # (Its measurements run in fresh worker processes: cold compiles, clean peak RSS.)
        scale.run(quick=args.quick, out_dir=out, console=console)
    return 0


if __name__ == "__main__":
    sys.exit(main())
