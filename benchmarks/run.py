"""The benchmark suite in one command: speed (`speed.py`) and accuracy (`accuracy.py`) of
jaxpose beside OpenCV and PoseLib, timed in the same run, and scaling (`scale.py`: time,
peak memory and compile time versus n and batch size).

    python benchmarks/run.py            # full (what the documentation's tables come from)
    python benchmarks/run.py --quick    # smaller sizes (10^3 problems), fewer repeats
    python benchmarks/run.py --only speed
    python benchmarks/run.py --only speed --sections latency p3p
    python -m benchmarks.run --only scale

Prints the tables and the speed targets table (each target of `speed.TARGETS` beside its
figure, its verdict, the peer's figure, the compile time and the machine; printed again
at the end when accuracy and scale ran too), writes `benchmarks/results/speed.json`
(targets and machine included; and the accuracy module's JSON and plots),
`benchmarks/results/batch.png` and `scale.json` / `scale.png` (`*_quick.*` with
`--quick`). Computes in float64 (x64 enabled for this process and the workers).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/run.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax

from benchmarks._harness import (
    RESULTS,
    machine,
    rich_console,
    times_faster,
    write_json,
)


def figure_text(value: float | None, unit: str | None) -> str:
    """A figure in its unit: `"1.23 ms"`, `"8.1x"`, `"99.95%"` (a share), `"-"` if none."""
    if value is None:
        return "-"
    if unit == "%":
        return f"{100 * value:.2f}%"
    if unit == "x":
        return f"{value:.1f}x"
    digits = 0 if abs(value) >= 100 else 1 if abs(value) >= 10 else 2
    return f"{value:.{digits}f} {unit}"


def print_targets(targets: dict, console, machine_info: dict | None = None) -> None:
    """The targets table: each target's figure, bound, verdict, peer and compile time."""
    from rich.table import Table

    title = "Speed targets"
    if machine_info:
        title += f" ({machine_info.get('cpu')}, {machine_info.get('cores')} cores)"
    t = Table(title=title)
    for col in ("target", "what", "figure", "bound", "verdict", "peer", "compile"):
        t.add_column(col, justify="left" if col in ("target", "what", "peer") else "right")
    for key, r in targets.items():
        sign = ">=" if r["higher_is_better"] else "<="
        bound = f"{100 * r['target']:g}%" if r["unit"] == "%" else f"{r['target']:g}{r['unit']}"
        bound = bound if r["unit"] in ("%", "x") else bound.replace(r["unit"], " " + r["unit"])
        style = {True: "green", False: "red"}.get(r["met"], "yellow")
        peer = "-"
        if r["peer"] is not None:
            peer = f"{figure_text(r['peer_figure'], r['peer_unit'])} {r['peer']}"
        t.add_row(
            key,
            r["what"],
            figure_text(r["figure"], r["unit"]),
            f"{sign} {bound}",
            f"[{style}]{r['verdict']}[/{style}]",
            peer,
            "-" if r["compile_s"] is None else f"{r['compile_s']:.1f} s",
        )
    console.print(t)


def print_speed(res: dict, console) -> None:
    """The sections' figures, then the targets table."""
    from rich.table import Table

    pe, p, ph = res.get("peers"), res.get("paper"), res.get("paper_phases")
    if pe:
        console.print(
            f"bench ({pe['triplets']} triplets): lean OpenCV loop {pe['opencv_loop_ms']:.1f} ms, "
            f"PoseLib loop {pe['poselib_loop_ms']:.1f} ms, SQPnP + RefineLM "
            f"{pe['sqpnp_lm_us']:.0f} us"
        )
    if p:
        console.print(
            f"paper protocol, jit(strategy.mixed) over all {p['triplets']} triplets: "
            f"{p['jaxpose_ms']:.2f} ms (compile {p['compile_s']:.1f} s)"
        )
    if ph:
        console.print(
            f"what it is made of (ms, each compiled alone): three-point roots "
            f"{ph['three_point_ms']:.2f}; step 1 (roots + Eq. 8 errors) {ph['step1_ms']:.2f}; "
            f"step 2 (linear from all {ph['triplets']}) {ph['step2_linear_ms']:.2f}; mixed "
            f"{ph['mixed_ms']:.2f}; solve (mixed + polish) {ph['solve_ms']:.2f}"
        )
    for name, row in (res.get("latency") or {}).items():
        console.print(
            f"solve_pnp, {name} (n = {row['n']}): {row['ms']:.2f} ms, compile "
            f"{row['compile_s']:.1f} s, RMS {row['rms_px']:.4f} px; SQPnP + RefineLM "
            f"{row['sqpnp_lm_us']:.0f} us, RMS {row['sqpnp_lm_rms_px']:.4f} px"
        )
        if "lean_opencv_loop_ms" in row:
            console.print(
                f"  side by side with the lean OpenCV loop ({row['lean_opencv_loop_ms']:.1f} "
                f"ms): {row['vs_lean_opencv']:.1f}x; the first call after the loop (code "
                f"and threads gone cold) {row['after_loop_ms']:.2f} ms"
            )
    if res.get("batch"):
        b = Table(title="Batches: n = 16, 1 px, solve_pnp_batch (defaults) vs OpenCV loop")
        for col in ("B", "jaxpose", "per problem", "OpenCV loop", "ratio", "at optimum", "compile"):
            b.add_column(col, justify="right")
        for row in res["batch"]:
            b.add_row(
                str(row["B"]),
                f"{1e3 * row['jaxpose_s']:.1f} ms",
                f"{row['per_problem_us']:.0f} us",
                f"{1e3 * row['opencv_s']:.1f} ms",
                times_faster(row["vs_opencv"], 2),
                f"{100 * row['at_optimum']:.2f}%",
                f"{row['compile_s']:.1f} s",
            )
        console.print(b)
    cl = res.get("classes")
    if cl:
        small, large = cl["sizes"]
        c = Table(title="Problem classes: solve_pnp_batch (defaults) vs the SQPnP + RefineLM loop")
        for col in (
            "class",
            f"per problem, B = {small}",
            f"per problem, B = {large}",
            "growth",
            "loop per problem",
            f"ratio, B = {large}",
            "at optimum",
        ):
            c.add_column(col, justify="right")
        for kind, row in cl["classes"].items():
            lo, hi = row[str(small)], row[str(large)]
            c.add_row(
                kind,
                f"{lo['per_problem_us']:.1f} us",
                f"{hi['per_problem_us']:.1f} us",
                f"{row['growth']:.2f}x",
                f"{row['opencv_us']:.0f} us",
                times_faster(hi["vs_opencv"], 2),
                f"{100 * min(lo['at_optimum'], hi['at_optimum']):.2f}%",
            )
        console.print(c)
    mem = res.get("batch_memory")
    if mem:
        if "failed" in mem:
            console.print(f"batch peak memory: failed ({mem['failed']})")
        else:
            console.print(
                f"batch peak memory (fresh process, B = {mem['B']}, VmHWM): "
                f"{mem['peak_mb']:.0f} MB ({mem['rss_before_call_mb']:.0f} MB before the call; "
                f"first call {mem['first_call_s']:.1f} s, then {mem['warm_s']:.2f} s)"
            )
    q = res.get("p3p")
    if q:
        console.print(
            f"three-point kernel: {q['ns_per_triplet']:.0f} ns per triplet over "
            f"{q['triplets']} ({100 * q['solved']:.2f}% solved); per call: cv2.solveP3P "
            f"{q['opencv_ns_per_triplet']:.0f} ns, poselib.p3p {q['poselib_ns_per_triplet']:.0f} ns"
        )
    ls = res.get("linear_step")
    if ls:
        ref = ls.get("reference_ns")
        console.print(
            f"linear step kernel (n = {ls['n']}, float64, {ls['problems']} problems per call): "
            f"{ls['ns']:.0f} ns per step"
            + (f"; vmapped reference {ref:.0f} ns" if ref is not None else "")
        )
    print_targets(res["targets"], console, res.get("machine"))


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
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, smaller batches")
    parser.add_argument("--only", choices=("speed", "accuracy", "scale"), default=None)
    parser.add_argument("--out", default=str(RESULTS))
    parser.add_argument(
        "--sections", nargs="+", default=None, help="speed sections to run (default: all)"
    )
    args = parser.parse_args(argv)
    # Compile times are figures here: jaxpose's program cache stays off (in this process
    # and the workers it spawns), so that a first call compiles (benchmarks/startup.py
    # measures the cache).
    os.environ["JAXPOSE_CACHE_DIR"] = "off"
    jax.config.update("jax_enable_x64", True)
    from benchmarks import accuracy, scale, speed

    console = rich_console(120)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    info = machine()
    console.print(f"machine: {info['cpu']}, {info['cores']} cores, devices {info['devices']}")
    res = None
    if args.only in (None, "speed"):
        with console.status("speed: compiling and timing..."):
            res = speed.run(quick=args.quick, sections=args.sections or speed.SECTIONS)
        res["machine"] = info
        res["quick"] = args.quick
        # A subset of the sections is saved apart, never over a whole run's results.
        name = "speed" + ("_quick" if args.quick else "") + ("_partial" if args.sections else "")
        path = write_json(out / f"{name}.json", res, indent=2)
        print_speed(res, console)
        if res.get("batch"):
            plot_batch(res, out / ("batch_quick.png" if args.quick else "batch.png"))
        console.print(f"wrote {path}")
    if args.only in (None, "accuracy"):
        accuracy.run(quick=args.quick, out_dir=out)
    if args.only in (None, "scale"):
        # (Its measurements run in fresh worker processes: cold compiles, clean peak RSS.)
        scale.run(quick=args.quick, out_dir=out, console=console)
    if res is not None and args.only is None:
        print_targets(res["targets"], console, info)
    return 0


if __name__ == "__main__":
    sys.exit(main())
