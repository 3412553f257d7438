"""`jaxpose reproduce`: the paper's experiment on the embedded bench, Table 1, the
figures, and optionally its rerun recording."""

from __future__ import annotations

import time
from pathlib import Path

from ._common import CliError, new_console, setup_jax
from ._recording import check_recording_args, make_recording, wants_recording

__all__ = ["cmd_reproduce"]


def cmd_reproduce(args) -> int:
    """Run `jaxpose reproduce` with the parsed `args`; returns the exit code."""
    from rich.table import Table

    console = new_console()
    setup_jax(not args.float32)
    from ..apps import _bench as _bench
    from ..apps import _experiment as _experiment
    from ..viz._figures import write_figures
    from ..viz._rerun_common import METHOD_LABELS

    if args.noise < 0:
        raise CliError(f"--noise must be >= 0, got {args.noise}")
    check_recording_args(args)
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
        f"triplets {c['triplets']} (paper {pc['triplets']}); aligned (area < 40 px^2 here): "
        f"{c['aligned']} (paper {pc['aligned']}); collinear model points: "
        f"{c['collinear_model']}; no three-point solution: {c['no_solution']}; "
        f"used {c['used']} (paper {pc['used']})"
    )
    stats = result.statistics()
    table = Table(title="Table 1: pose error (mm) per method: ours / paper")
    table.add_column("")
    for m in _experiment.METHOD_NAMES:
        table.add_column(METHOD_LABELS[m], justify="right")
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
        figures = [] if args.no_figures else write_figures(result, out)
    except OSError as exc:
        raise CliError(f"cannot write to --out {out}: {exc}") from exc
    console.print(f"wrote {json_path}" + "".join(f", {p}" for p in figures))
    if wants_recording(args):
        from ..viz._rerun_experiment import log_experiment

        mix = result.mixed
        from ..viz._overlay import render_bench

        picture = render_bench(bench)[..., ::-1].copy()  # the bench seen by its camera (RGB)
        make_recording(
            args,
            console,
            "jaxpose reproduce",
            lambda rec: log_experiment(rec, bench, result, mix, image=picture),
        )
    return 0
