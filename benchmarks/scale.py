"""Scaling of jaxpose: time, peak memory and compile time versus the number of matches `n`
and the batch size `B` (targets in `TARGETS`).

Sections (float64, x64 enabled by this script and by each of its worker processes):

- `n`: one problem (`jaxpose.apps.random_scene`, 1 px noise, a general 3x4 camera) solved by a
  jitted `jaxpose.solve` for `n` in (4, 6, 10, 16, 20, 50, 100, 200), with three ways to
  pick the triplets:
  - `exhaustive`: all `C(n, 3)` (`max_triplets=None`); grows as `n^3 / 6` triplets, each
    scored over all `n` matches, so its cost grows as `n^4`;
  - `sampled`: the library's default `max_triplets=2000`: exhaustive while
    `C(n, 3) <= 2000` (n <= 23), above that a fixed, seeded uniform sample of 2000
    triplets (`jaxpose.strategy.triplet_indices(n, 2000)`), so the cost grows as `n` only;
  - `budget8`: `triplet_budget=8`, the 8 candidate triplets with the largest image
    triangles (`jaxpose.strategy.spread_triplets`), the fast path for batches.
  Per configuration: warm time (minimum over repeats of the compiled call), compile time
  (trace + lower, and XLA's compile, apart; the first call minus the warm one), the
  triplets solved, XLA's own memory figure of the compiled program
  (`memory_analysis()`: temp + argument + output bytes) and, as a cross-check, the
  growth of the worker process's peak RSS (`ru_maxrss`). Every configuration runs in a
  fresh worker process (`benchmarks/_scale_workers.py`: every compile is cold);
  exhaustive runs above `exhaustive_max` triplets are skipped and their time projected
  from the `T * n` cost model fitted on the measured ones.
- `batch`: `jaxpose.solve_pnp_batch(n=16, triplet_budget=8)` for `B` in (1, 10, 100, 1000,
  10^4[, 10^5, 10^6]) beside a loop of `cv2.solvePnP(SQPNP)` + `cv2.solvePnPRefineLM` (per
  problem time from at most 2000 problems), with `chunk_size` in (None, 1000, 100) at the
  largest batches: the memory of one chunk's program (XLA) and the worker's RSS growth
  show that chunking bounds memory. Large batches tile a pool of 10^4 distinct problems.
- `cache`: cold compile against JAX's persistent compilation cache: the workers share a
  fresh `jax_compilation_cache_dir` (`jax_persistent_cache_min_compile_time_secs=0`); a
  configuration run again in a new process loads its executable from the cache (the
  trace and lowering to StableHLO are not cached: they are paid again).

    python benchmarks/scale.py --quick   # n in (6, 16, 50), B up to 10^4
    python benchmarks/scale.py           # everything (about half an hour on 2 cores)

Prints tables (`_scale_report.py`), writes `benchmarks/results/scale.json`
(`scale_quick.json`) and a plot `scale.png` (`scale_quick.png`). `run(quick, out_dir=...)`
is the entry point for `benchmarks/run.py`; `main(argv)` the command line, both return
the result dict.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from math import comb
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/scale.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._harness import (
    K_PIXELS,
    RESULTS,
    Stopwatch,
    batch_problems,
    machine,
    opencv_block,
    rich_console,
    spawn,
    timeit,
    write_json,
)
from benchmarks._scale_report import plot as plot
from benchmarks._scale_report import print_tables as print_tables
from benchmarks._scale_workers import WORKERS

TARGETS = {"compile_s": 5.0, "latency_ms": 5.0}

N_FULL = (4, 6, 10, 16, 20, 50, 100, 200)
N_QUICK = (6, 16, 50)
B_FULL = (1, 10, 100, 1000, 10_000, 100_000)
B_QUICK = (1, 10, 100, 1000, 10_000)
BUDGET = 8
SAMPLE = 2000  # the library's default max_triplets


def _spawn(spec: dict, in_process: bool, timeout: float) -> dict:
    """Run one worker: in a fresh Python process (default), or here (`in_process`)."""
    if not in_process:
        return spawn("benchmarks._scale_workers", spec, timeout=timeout)
    try:
        return WORKERS[spec["kind"]](spec)
    except Exception as e:  # pragma: no cover (reported, not fatal)
        return {"failed": f"{type(e).__name__}: {e}"}


# ----------------------------------------------------------------------------- sections


def _strategies(n: int, exhaustive_max: int, budget_n=None) -> list[dict]:
    """The configurations measured at `n` (a strategy is skipped where it would repeat
    another: below 2000 triplets `sampled` is `exhaustive`, below 8 so is `budget8`)."""
    T = comb(n, 3)
    out = []
    if T <= exhaustive_max:
        out.append({"strategy": "exhaustive", "max_triplets": None, "triplet_budget": None})
    if T > SAMPLE:
        out.append({"strategy": "sampled", "max_triplets": SAMPLE, "triplet_budget": None})
    if min(T, SAMPLE) > BUDGET and (budget_n is None or n in budget_n):
        out.append({"strategy": "budget8", "max_triplets": SAMPLE, "triplet_budget": BUDGET})
    return out


def _fit_exhaustive(rows: list[dict]) -> float | None:
    """Seconds per (triplet x match) of the exhaustive strategy, from its largest runs."""
    ex = [r for r in rows if r["strategy"] == "exhaustive" and "warm_s" in r and r["n"] >= 16]
    if not ex:
        return None
    ex = sorted(ex, key=lambda r: r["n"])[-2:]
    return float(sum(r["warm_s"] / (r["triplets_solved"] * r["n"]) for r in ex) / len(ex))


def _switch(rows: list[dict]) -> dict:
    """Where exhaustive triplets stop paying: the smallest measured `n` where the
    exhaustive run costs more than twice the sampled one while the sample reaches the
    same answer (final error within 1e-6 px), and where it passes the latency target."""
    by = {(r["n"], r["strategy"]): r for r in rows if "warm_s" in r}
    latency = [
        n
        for (n, s), r in sorted(by.items())
        if s == "exhaustive" and 1e3 * r["warm_s"] > TARGETS["latency_ms"]
    ]
    stop, compared = None, []
    for (n, s), r in sorted(by.items()):
        if s != "exhaustive" or (n, "sampled") not in by:
            continue
        smp = by[(n, "sampled")]
        same = abs(r["error_px"] - smp["error_px"]) <= 1e-6
        ratio = r["warm_s"] / smp["warm_s"]
        cpu = r.get("warm_cpu_s", r["warm_s"]) / max(smp.get("warm_cpu_s", smp["warm_s"]), 1e-12)
        compared.append(
            {
                "n": n,
                "exhaustive_over_sampled": ratio,
                "exhaustive_over_sampled_cpu": cpu,
                "same_answer": same,
                "error_px": [r["error_px"], smp["error_px"]],
            }
        )
        if stop is None and ratio > 2 and same:
            stop = n
    library = next(n for n in range(3, 1000) if comb(n, 3) > SAMPLE)
    text = (
        f"The library switches from exhaustive to a fixed seeded sample of {SAMPLE} triplets "
        f"when C(n, 3) > {SAMPLE}, i.e. from n = {library} (max_triplets={SAMPLE}); "
        f"triplet_budget={BUDGET} keeps the {BUDGET} largest image triangles among those. "
    )
    if stop is not None:
        text += (
            f"Measured: exhaustive stops paying at n = {stop} (the {comb(stop, 3)} triplets "
            f"cost {next(c['exhaustive_over_sampled'] for c in compared if c['n'] == stop):.1f}x "
            f"the {SAMPLE}-sample, which reaches the same answer; the measured n below it "
            f"have C(n, 3) <= {SAMPLE}, where the two are the same set)"
        )
    else:
        text += "Measured: no n where the sample was both >2x faster and at the same answer"
    if latency:
        text += (
            f"; the exhaustive single call passes the {TARGETS['latency_ms']:g} ms latency "
            f"target from n = {latency[0]}."
        )
    else:
        text += "."
    return {
        "library_switch_n": library,
        "max_triplets": SAMPLE,
        "exhaustive_stops_paying_n": stop,
        "exhaustive_over_latency_target_from_n": latency[0] if latency else None,
        "compared": compared,
        "text": text,
    }


def n_section(
    n_values, exhaustive_max, repeat, cache_dir, in_process, method, log, budget_n=None
) -> dict:
    rows = []
    for n in n_values:
        for cfg in _strategies(n, exhaustive_max, budget_n):
            spec = {"kind": "single", "n": n, "method": method, "repeat": repeat, **cfg}
            spec["cache_dir"] = cache_dir
            log(f"n = {n}, {cfg['strategy']}: compiling and timing")
            row = _spawn(spec, in_process, timeout=1200)
            rows.append({"n": n, **cfg, **row})
        if comb(n, 3) > exhaustive_max:
            rows.append(
                {
                    "n": n,
                    "strategy": "exhaustive",
                    "max_triplets": None,
                    "triplet_budget": None,
                    "triplets_exhaustive": comb(n, 3),
                    "skipped": f"C(n, 3) = {comb(n, 3)} > {exhaustive_max}",
                }
            )
    per = _fit_exhaustive(rows)
    for r in rows:
        if "skipped" in r and per is not None:
            r["projected_warm_s"] = per * r["triplets_exhaustive"] * r["n"]
    return {"rows": rows, "exhaustive_s_per_triplet_match": per, "switch": _switch(rows)}


def _opencv_per_problem(count: int, n: int = 16, seed: int = 1, repeat: int = 5):
    """Seconds per problem of the OpenCV loop: the least wall and CPU time over `repeat`
    loops of (at most) 100 problems each (successive blocks of the batch), a duration
    like that of a B = 100 call."""
    obj, img = batch_problems(count, n, seed=seed)
    m = min(count, 100)
    starts = iter(range(0, max(count - m, 0) + 1, m))
    t = timeit(
        lambda: opencv_block(obj, img, K_PIXELS, next(starts, 0), m),
        warmup=0,
        repeat=repeat,
        budget_s=30.0,
        block=False,
    )
    return t.best / m, t.cpu / m


def _batch_configs(sizes, quick: bool, one_call_max: int, chunks) -> list[tuple[int, int | None]]:
    """(B, chunk_size) pairs: one call up to `one_call_max` problems; above, chunks of each
    of `chunks` (the smallest only up to 10^4 problems) and, in full mode up to 10^4
    problems, the whole batch at once for the memory comparison."""
    out = []
    for B in sizes:
        if B <= one_call_max:
            out.append((B, None))
            continue
        if B <= 10_000 and not quick:
            out.append((B, None))
        for c in sorted(chunks, reverse=True):
            if c == max(chunks) or B <= 10_000:
                out.append((B, c))
    return out


def batch_section(
    sizes, quick, repeat, cache_dir, in_process, method, log, one_call_max=1000, chunks=(1000, 100)
) -> dict:
    log("OpenCV loop (SQPnP + RefineLM): timing")
    per_cv, per_cv_cpu = _opencv_per_problem(min(max(sizes), 2000))
    rows = []
    for B, chunk_size in _batch_configs(sizes, quick, one_call_max, chunks):
        spec = {
            "kind": "batch",
            "B": B,
            "chunk_size": chunk_size,
            "method": method,
            "triplet_budget": BUDGET,
            "repeat": repeat if B <= 1000 else 1,
            "cache_dir": cache_dir,
        }
        log(f"B = {B}, chunk_size = {chunk_size}: compiling and timing")
        row = _spawn(spec, in_process, timeout=3000)
        row = {"B": B, "chunk_size": chunk_size, **row}
        if "warm_s" in row:
            row["opencv_s"] = per_cv * B
            row["opencv_per_problem_us"] = 1e6 * per_cv
            row["vs_opencv"] = per_cv * B / row["warm_s"]
            row["opencv_per_problem_cpu_us"] = 1e6 * per_cv_cpu
            row["vs_opencv_cpu"] = per_cv_cpu * B / max(row["warm_cpu_s"], 1e-12)
        rows.append(row)
    return {
        "rows": rows,
        "opencv_per_problem_us": 1e6 * per_cv,
        "opencv_per_problem_cpu_us": 1e6 * per_cv_cpu,
    }


def cache_section(n_rows, b_rows, configs, cache_dir, in_process, log) -> dict:
    """Configurations run again in a fresh process: their executables now come from the
    persistent cache that their first (cold) run filled."""
    if in_process or cache_dir is None:
        return {"skipped": "needs fresh worker processes and a cache directory", "rows": []}
    rows = []
    for kind, key in configs:
        cold = next(
            (r for r in (n_rows if kind == "single" else b_rows) if _key(kind, r) == key), None
        )
        if cold is None or "failed" in cold or "skipped" in cold:
            continue
        spec = {k: cold[k] for k in _SPEC_KEYS[kind]}
        spec.update(kind=kind, cache_dir=cache_dir, repeat=1)
        log(f"cached compile: {kind} {key}")
        hot = _spawn(spec, in_process, timeout=1200)
        if "failed" in hot:
            rows.append({"kind": kind, "config": list(key), "failed": hot["failed"]})
            continue
        row = {"kind": kind, "config": list(key), "cold_compile_s": cold["compile_s"]}
        row["cached_compile_s"] = hot["compile_s"]
        if kind == "single":
            row.update(
                cold_lower_s=cold["lower_s"],
                cold_xla_s=cold["xla_compile_s"],
                cached_lower_s=hot["lower_s"],
                cached_xla_s=hot["xla_compile_s"],
                cached_rss_growth_mb=hot["rss_growth_mb"],
                cold_rss_growth_mb=cold["rss_growth_mb"],
            )
        else:
            row.update(
                cached_rss_growth_mb=hot["rss_growth_mb"], cold_rss_growth_mb=cold["rss_growth_mb"]
            )
        rows.append(row)
    # Chunked batches run a program that a smaller batch compiled before: a cache hit too.
    for r in b_rows:
        cold = next(
            (c for c in b_rows if c.get("B") == r.get("chunk") and c.get("chunk_size") is None),
            None,
        )
        if r.get("chunk_size") is None or cold is None or "warm_s" not in r or "warm_s" not in cold:
            continue
        rows.append(
            {
                "kind": "batch",
                "config": [r["B"], r["chunk_size"]],
                "cold_compile_s": cold["compile_s"],
                "cached_compile_s": r["compile_s"],
                "cold_rss_growth_mb": cold["rss_growth_mb"],
                "cached_rss_growth_mb": r["rss_growth_mb"],
                "note": f"program of B = {cold['B']} (one call) reused by chunks of {r['chunk']}",
            }
        )
    return {"rows": rows, "target_s": TARGETS["compile_s"]}


_SPEC_KEYS = {
    "single": ("n", "strategy", "max_triplets", "triplet_budget", "method"),
    "batch": ("B", "chunk_size", "method", "triplet_budget"),
}


def _key(kind: str, row: dict) -> tuple:
    if kind == "single":
        return (row.get("n"), row.get("strategy"))
    return (row.get("B"), row.get("chunk_size"))


# ----------------------------------------------------------------------------- entry points


def run(
    quick: bool = False,
    *,
    out_dir: str | Path | None = None,
    console=None,
    n_values=None,
    batch_sizes=None,
    method: str = "mixed",
    repeat: int | None = None,
    exhaustive_max: int | None = None,
    in_process: bool = False,
    cache: bool = True,
    cache_configs=None,
    one_call_max: int = 1000,
    chunks=(1000, 100),
) -> dict:
    """Measure every section; with `out_dir`, write the JSON and the plot there and print
    the tables. Returns the result dict."""
    console = console or rich_console(140)
    n_values = tuple(n_values or (N_QUICK if quick else N_FULL))
    batch_sizes = tuple(batch_sizes or (B_QUICK if quick else B_FULL))
    repeat = repeat or (3 if quick else 5)
    exhaustive_max = exhaustive_max or (20_000 if quick else 200_000)
    watch = Stopwatch()
    load = [os.getloadavg()]

    def log(msg: str) -> None:
        load.append(os.getloadavg())
        console.log(msg)

    with tempfile.TemporaryDirectory(prefix="jaxpose-scale-cache-") as tmp:
        cache_dir = tmp if cache and not in_process else None
        budget_n = (16,) if quick else None  # quick: the budgeted path at n = 16 only
        nres = n_section(
            n_values, exhaustive_max, repeat, cache_dir, in_process, method, log, budget_n
        )
        bres = batch_section(
            batch_sizes, quick, repeat, cache_dir, in_process, method, log, one_call_max, chunks
        )
        if cache_configs is None:
            singles = [("single", _key("single", r)) for r in nres["rows"] if "warm_s" in r]
            batches = [
                ("batch", _key("batch", r))
                for r in bres["rows"]
                if "warm_s" in r and r["chunk_size"] is None
            ]
            if quick:  # the paper-size problem only (chunked batches reuse programs anyway)
                singles = [s for s in singles if s[1] == (16, "exhaustive")]
                batches = []
            cache_configs = singles + batches
        cres = cache_section(nres["rows"], bres["rows"], cache_configs, cache_dir, in_process, log)
    load.append(os.getloadavg())
    res = {
        "n": nres,
        "batch": bres,
        "cache": cres,
        "targets": TARGETS,
        "quick": quick,
        "method": method,
        "in_process": in_process,
        "load_average": {
            "max_1min": max(x[0] for x in load),
            "min_1min": min(x[0] for x in load),
            "samples": [list(x) for x in load],
        },
        "machine": machine(),
        "seconds": watch.seconds,
    }
    if out_dir is not None:
        out = Path(out_dir)
        name = "scale_quick" if quick else "scale"
        write_json(out / f"{name}.json", res, indent=2)
        plot(res, out / f"{name}.png")
        print_tables(res, console)
        console.print(
            f"wrote {out / (name + '.json')} and {name}.png ({res['seconds']:.0f} s; load "
            f"{res['load_average']['min_1min']:.1f}-{res['load_average']['max_1min']:.1f})"
        )
    return res


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="n in (6, 16, 50), B up to 10^4")
    parser.add_argument("--out", dest="out_dir", metavar="OUT", default=str(RESULTS))
    parser.add_argument(
        "--n", dest="n_values", metavar="N", type=int, nargs="+", help="numbers of matches"
    )
    parser.add_argument(
        "--batch", dest="batch_sizes", metavar="BATCH", type=int, nargs="+", help="batch sizes"
    )
    parser.add_argument("--method", default="mixed")
    parser.add_argument("--repeat", type=int, default=None)
    parser.add_argument("--exhaustive-max", type=int, default=None)
    parser.add_argument("--chunks", type=int, nargs="+", default=[1000, 100])
    parser.add_argument("--one-call-max", type=int, default=1000, help="larger B: chunked")
    parser.add_argument("--in-process", action="store_true", help="no worker processes")
    parser.add_argument(
        "--no-cache", dest="cache", action="store_false", help="skip the compile-cache runs"
    )
    args = parser.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    return run(**vars(args))  # every option is named after its keyword of `run`


if __name__ == "__main__":
    main()
