"""The `jaxpose` command line: `reproduce` (the paper's experiment) and `bench`."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

__all__ = ["main"]


class CliError(Exception):
    """An error to report as one line, without a traceback."""


def _console():
    from rich.console import Console

    # Table 1 needs about 100 columns; rich falls back to 80 when output is not a terminal.
    return Console(width=None if sys.stdout.isatty() else 110)


def _setup_jax(x64: bool = True) -> None:
    import jax

    # The command line owns its process: float64 (OpenCV-level accuracy) unless asked not
    # to, and JAX's persistent compilation cache so that a second run starts fast.
    jax.config.update("jax_enable_x64", x64)
    cache = Path.home() / ".cache" / "jaxpose" / "xla"
    try:
        cache.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(cache))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except OSError:  # pragma: no cover - read-only home
        pass


def _cmd_reproduce(args) -> int:
    from rich.table import Table

    console = _console()
    _setup_jax(not args.float32)
    from . import _bench, _experiment

    if args.noise < 0:
        raise CliError(f"--noise must be >= 0, got {args.noise}")
    bench = _bench.default_bench(seed=args.seed, noise=args.noise)
    console.print(
        f"[bold]jaxpose reproduce[/]: cross prism, {len(bench.model_points)} matched vertices, "
        f"noise {bench.noise:g} px (seed {bench.seed}), camera f = {bench.K[0, 0]:g} px, "
        f"image {bench.image_size[0]}x{bench.image_size[1]}"
    )
    t0 = time.perf_counter()
    with console.status("compiling and solving all triplets with the four methods..."):
        result = _experiment.run_experiment(bench, threshold=args.threshold)
    t1 = time.perf_counter()
    with console.status("solving again (compiled)..."):
        result = _experiment.run_experiment(bench, threshold=args.threshold)
    t2 = time.perf_counter()
    c = result.counts
    pc = _experiment.PAPER_COUNTS
    console.print(
        f"triplets {c['triplets']} (paper {pc['triplets']}); aligned, area < 40 px^2: "
        f"{c['aligned']} (paper {pc['aligned']}); collinear model points: "
        f"{c['collinear_model']}; no three-point solution: {c['no_solution']}; "
        f"used {c['used']} (paper {pc['used']})"
    )
    stats = result.statistics()
    table = Table(title="Table 1: pose error (mm) per method: ours / paper")
    table.add_column("")
    labels = {
        "three_point": "3-segment",
        "nonlinear": "non-linear",
        "linear": "linear",
        "mixed": "mixed",
    }
    for m in _experiment.METHOD_NAMES:
        table.add_column(labels[m], justify="right")
    rows = [
        ("mean", "mean"),
        ("standard deviation", "std"),
        ("mean deviation", "mean_deviation"),
        ("minimum", "min"),
    ]
    for label, key in rows:
        table.add_row(
            label,
            *(
                f"{stats[m][key]:.3f} / {_experiment.PAPER_TABLE1[m][key]:.3f}"
                for m in _experiment.METHOD_NAMES
            ),
        )
    table.add_row(
        "at the optimum",
        *(f"{100 * stats[m]['at_optimum']:.2f}%" for m in _experiment.METHOD_NAMES),
    )
    console.print(table)
    console.print(
        f"optimum pose error {result.optimum:.3f} mm (paper 0.578); mixed at the optimum "
        f"{100 * stats['mixed']['at_optimum']:.2f}% of used triplets (paper "
        f"{100 * _experiment.PAPER_MIXED_AT_OPTIMUM:.2f}%); acceptance threshold "
        f"{result.threshold:.3f} px"
    )
    console.print(f"mixed statuses: {result.status_counts('mixed')}")
    console.print(
        f"time: first run (compile + solve) {t1 - t0:.1f} s, compiled run {1e3 * (t2 - t1):.1f} ms"
    )
    out = Path(args.out)
    try:
        json_path = _experiment.write_json(result, out / "results.json")
        figures = [] if args.no_figures else _experiment.write_figures(result, out)
    except OSError as exc:
        raise CliError(f"cannot write to --out {out}: {exc}") from exc
    console.print(f"wrote {json_path}" + "".join(f", {p}" for p in figures))
    return 0


def _cmd_bench(args) -> int:
    from rich.table import Table

    console = _console()
    _setup_jax(True)
    import cv2
    import jax
    import jax.numpy as jnp
    import numpy as np

    from . import _bench
    from ._api import solve

    bench = _bench.default_bench(seed=args.seed)
    C, M, I = (jnp.asarray(x) for x in (bench.camera, bench.model_points, bench.image_points))
    f = jax.jit(lambda C, M, I: solve(C, M, I, method="mixed"))
    with console.status("compiling the mixed algorithm..."):
        t0 = time.perf_counter()
        jax.block_until_ready(f(C, M, I))
        compile_s = time.perf_counter() - t0
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(f(C, M, I))
        times.append(time.perf_counter() - t0)
    ours = float(np.median(times))

    # The equivalent OpenCV loop: P3P per triplet, best root over all matches, LM refine.
    from ._mixed import triplet_indices

    K = bench.K
    world = np.asarray(bench.model_points)
    img = np.asarray(bench.image_points)
    trip = triplet_indices(len(world))

    def opencv_loop():
        best = None
        for ijk in trip:
            try:
                n, rvecs, tvecs = cv2.solveP3P(
                    world[ijk], img[ijk], K, None, flags=cv2.SOLVEPNP_P3P
                )
            except cv2.error:
                continue
            for rv, tv in zip(rvecs[:n], tvecs[:n]):
                proj, _ = cv2.projectPoints(world, rv, tv, K, None)
                e = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, 1))))
                if np.isfinite(e) and (best is None or e < best[0]):
                    best = (e, rv, tv)
            if best is not None:
                cv2.solvePnPRefineLM(world, img, K, None, best[1].copy(), best[2].copy())
        return best

    t0 = time.perf_counter()
    for _ in range(max(1, args.repeat // 10)):
        opencv_loop()
    cv = (time.perf_counter() - t0) / max(1, args.repeat // 10)
    table = Table(title=f"paper protocol: all {len(trip)} triplets of the bench")
    table.add_column("solver")
    table.add_column("time", justify="right")
    table.add_column("ratio", justify="right")
    table.add_row("jaxpose mixed (compiled)", f"{1e3 * ours:.2f} ms", "1.0x")
    table.add_row(
        "OpenCV loop (solveP3P, best root, RefineLM)",
        f"{1e3 * cv:.2f} ms",
        f"{cv / ours:.1f}x slower",
    )
    console.print(table)
    console.print(
        f"compile (first call): {compile_s:.1f} s. For the full benchmark suite: `make bench`."
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxpose",
        description="Pose recovery of a known 3D object from one calibrated image "
        "(Shaheen, Mallem & Chavand 2001), in JAX.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("reproduce", help="run the paper's experiment on the embedded bench")
    p.add_argument("--seed", type=int, default=0, help="image-noise seed (default 0)")
    p.add_argument(
        "--noise", type=float, default=None, help="pixel noise sigma (default: the bench's)"
    )
    p.add_argument(
        "--threshold",
        type=float,
        default=None,
        help="mixed acceptance threshold in px (default: adaptive)",
    )
    p.add_argument("--out", default="results", help="output folder (default ./results)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--float32", action="store_true", help="compute in float32")
    p.set_defaults(func=_cmd_reproduce)
    b = sub.add_parser("bench", help="time the paper protocol against OpenCV's loop")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--repeat", type=int, default=20)
    b.set_defaults(func=_cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    if getattr(args, "noise", 0) is None:
        from ._bench import DEFAULT_NOISE

        args.noise = DEFAULT_NOISE
    try:
        return args.func(args)
    except CliError as exc:
        print(f"jaxpose {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
