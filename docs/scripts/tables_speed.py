"""Tables of the speed and scaling benchmarks (`benchmarks/run.py`, `benchmarks/scale.py`)."""

from __future__ import annotations

from pathlib import Path

from tables_format import Missing, caption, duration, load, megabytes, share, table, verdict


def _run_command(data: dict, only: str) -> str:
    return f"python benchmarks/run.py --only {only}" + (" --quick" if data.get("quick") else "")


def _target_row(
    what: str, seconds: float, value: float, target: float, unit: str, peer="", ratio=""
) -> tuple[str, ...]:
    """A row of the speed table whose `value` has a target: a ratio to a peer (`unit`
    "x") must reach it, a time (any other unit) must stay under it."""
    higher = unit == "x"
    bound = f"{'>=' if higher else '<='} {target:g}{unit}"
    return (what, duration(seconds), peer, ratio, bound, verdict(value, target, higher))


def speed(results: Path) -> str:
    d, name = load(results, "speed.json", "speed_quick.json")
    T, p, lat = d["targets"], d["paper"], d["latency"]
    t3 = d["p3p"]
    paper_s = 1e-3 * p["jaxpose_ms"]
    sqpnp = f"`cv2.solvePnP` (SQPNP) {duration(1e-6 * lat['cv2_sqpnp_us'])}"

    def vs_sqpnp(key: str) -> str:
        return f"{1e-3 * lat['cv2_sqpnp_us'] / lat[key]:.2g}x"

    peers = (
        (f"paper protocol: all {p['triplets']} triplets of the bench, mixed", "OpenCV", "opencv"),
        ("same, against PoseLib", "PoseLib", "poselib"),
    )
    rows = [
        _target_row(
            what,
            paper_s,
            p[f"vs_{key}"],
            T[f"paper_vs_{key}"],
            "x",
            peer=f"{peer} loop {duration(1e-3 * p[f'{key}_ms'])}",
            ratio=f"{p[f'vs_{key}']:.1f}x",
        )
        for what, peer, key in peers
    ]
    rows += [
        _target_row("same, absolute", paper_s, p["jaxpose_ms"], T["paper_ms"], " ms"),
        _target_row(
            "one `solve_pnp` call, exhaustive mixed (Python included)",
            1e-3 * lat["solve_pnp_ms"],
            lat["solve_pnp_ms"],
            T["latency_ms"],
            " ms",
            peer=sqpnp,
            ratio=vs_sqpnp("solve_pnp_ms"),
        ),
        (
            "one `solve_pnp` call, `triplet_budget=8`",
            duration(1e-3 * lat["solve_pnp_budget8_ms"]),
            sqpnp,
            vs_sqpnp("solve_pnp_budget8_ms"),
            "",
            "",
        ),
        _target_row(
            f"three-point solver alone, per triplet ({t3['triplets']} vmapped)",
            1e-9 * t3["ns_per_triplet"],
            t3["ns_per_triplet"],
            T["p3p_ns_per_triplet"],
            " ns",
        ),
        _target_row(
            "cold compile of `solve` (bench)", p["compile_s"], p["compile_s"], T["compile_s"], " s"
        ),
    ]
    header = ("what", "jaxpose", "peer", "ratio (peer / jaxpose)", "target", "verdict")
    return table(header, rows) + "\n\n" + caption(d, name, command=_run_command(d, "speed"))


def speed_phases(results: Path) -> str:
    d, name = load(results, "speed.json", "speed_quick.json")
    ph = d["paper_phases"]
    rows = [
        ("three-point roots of every triplet", ph["three_point_ms"]),
        ("step 1: the roots and the Eq. 8 error of each over all matches", ph["step1_ms"]),
        ("step 2: the linear method from every triplet's pose", ph["step2_linear_ms"]),
        ("the mixed algorithm (`jaxpose.mixed`)", ph["mixed_ms"]),
        ("`jaxpose.solve` (mixed, then the final polish)", ph["solve_ms"]),
    ]
    out = table(
        (f"phase ({ph['triplets']} triplets, each compiled and timed alone)", "time"),
        [(what, duration(1e-3 * ms)) for what, ms in rows],
    )
    la = d.get("linalg")
    if la:
        out += "\n\n" + table(
            (f"6x6 normal equations ({la['systems']} systems at once)", "per system"),
            [
                ("`jnp.linalg.solve` (LAPACK)", duration(1e-6 * la["lapack_us_per_system"])),
                ("unrolled Cholesky", duration(1e-6 * la["unrolled_us_per_system"])),
            ],
        )
    return out + "\n\n" + caption(d, name, command=_run_command(d, "speed"))


def speed_batch(results: Path) -> str:
    d, name = load(results, "speed.json", "speed_quick.json")
    T = d["targets"]
    rows = [
        (
            r["B"],
            duration(r["jaxpose_s"]),
            duration(1e-6 * r["per_problem_us"]),
            duration(r["opencv_s"] / r["B"]),
            f"{r['vs_opencv']:.2f}x",
            share(r["at_optimum"]),
            verdict(r["at_optimum"], T["batch_at_optimum"], True),
        )
        for r in d["batch"]
    ]
    header = (
        "B",
        "jaxpose call",
        "per problem",
        "OpenCV loop, per problem",
        "ratio (OpenCV / jaxpose)",
        "at the OpenCV optimum",
        f"target >= {share(T['batch_at_optimum'], 1)}",
    )
    note = (
        f"`solve_pnp_batch(triplet_budget=8)`, n = 16, against a loop of `cv2.solvePnP` (SQPNP) "
        f"and `solvePnPRefineLM`. Speed target: >= {T['batch_vs_opencv_at_1e4']:g}x the "
        "OpenCV loop at B = 10^4 (measured by `benchmarks/scale.py`, below)."
    )
    return (
        note
        + "\n\n"
        + table(header, rows)
        + "\n\n"
        + caption(d, name, command=_run_command(d, "speed"))
    )


# ----------------------------------------------------------------------------- scaling


def _strategy(r: dict) -> str:
    if r.get("triplet_budget"):
        return f"`triplet_budget={r['triplet_budget']}`"
    if r.get("strategy") == "sampled":
        return f"sample of {r.get('max_triplets')}"
    return "all" if r.get("strategy") == "exhaustive" else str(r.get("strategy"))


def scale_n(results: Path) -> str:
    d, name = load(results, "scale.json", "scale_quick.json")
    targets = d.get("targets", {})
    names = [name]
    rows = list(d["n"]["rows"])
    try:
        large, large_name = load(results, "scale_large_n.json")
        rows += large["rows"]
        names.append(large_name)
    except Missing:
        pass
    lat = targets.get("latency_ms")
    out_rows = []
    for r in sorted(rows, key=lambda r: r["n"]):
        if "warm_s" not in r:
            out_rows.append(
                (r["n"], _strategy(r), f"{r['triplets_exhaustive']:,}", "not run", "", "", "", "")
            )
            continue
        out_rows.append(
            (
                r["n"],
                _strategy(r),
                f"{r['triplets_solved']:,} of {r['triplets_exhaustive']:,}",
                f"{duration(r['warm_s'])} ({duration(r['warm_cpu_s'])})",
                verdict(1e3 * r["warm_s"], lat, False) if lat else "",
                f"{duration(r['compile_s'])} ({duration(r['lower_s'])} + "
                f"{duration(r['xla_compile_s'])})",
                megabytes(r["memory"]["peak_bytes"]),
                f"{r['run_rss_growth_mb']:.3g} MB",
            )
        )
    header = (
        "n",
        "triplets",
        "solved",
        "warm call, wall (CPU)",
        f"latency target <= {lat:g} ms" if lat else "latency target",
        "cold compile (trace + XLA)",
        "XLA memory",
        "RSS while running",
    )
    text = [table(header, out_rows)]
    for c in d["n"].get("switch", {}).get("compared", []):
        text.append(
            f"At n = {c['n']}, all triplets cost {c['exhaustive_over_sampled']:.1f}x the "
            f"sample in wall time ({c['exhaustive_over_sampled_cpu']:.1f}x in CPU time), "
            + ("for the same answer." if c.get("same_answer") else "for a different answer.")
        )
    text.append(caption(d, *names, command=_run_command(d, "scale")))
    return "\n\n".join(text)


def scale_batch(results: Path) -> str:
    d, name = load(results, "scale.json", "scale_quick.json")
    names = [name]
    rows = list(d["batch"]["rows"])
    try:
        big, big_name = load(results, "scale_batch_1e5.json")
        rows.append(big)
        names.append(big_name)
    except Missing:
        pass
    cpu_peer = d["batch"].get("opencv_per_problem_cpu_us")
    try:
        target = load(results, "speed.json", "speed_quick.json")[0]["targets"]
        target = target["batch_vs_opencv_at_1e4"]
    except (Missing, KeyError):
        target = None
    out_rows = []
    for r in rows:
        ratio = cpu_peer / r["per_problem_cpu_us"] if cpu_peer else None
        out_rows.append(
            (
                f"{r['B']:,}",
                str(r["chunk_size"]) if r.get("chunk_size") else "-",
                f"{duration(1e-6 * r['per_problem_us'])} / "
                f"{duration(1e-6 * r['per_problem_cpu_us'])}",
                "-" if ratio is None else f"{ratio:.2f}x",
                verdict(ratio, target, True) if target and ratio and r["B"] >= 10_000 else "",
                megabytes(r["memory"]["peak_bytes"]),
                f"{r['run_rss_growth_mb']:.3g} MB",
                f"{r['input_mb']:.3g} MB",
                share(r.get("ok")),
            )
        )
    header = (
        "B",
        "`chunk_size`",
        "per problem, wall / CPU",
        "ratio (OpenCV CPU / jaxpose CPU)",
        f"target >= {target:g}x at B >= 10^4" if target else "target",
        "XLA memory per chunk",
        "RSS while running",
        "inputs",
        "accepted",
    )
    note = (
        "`solve_pnp_batch(triplet_budget=8)`, n = 16, one fresh process per row; the OpenCV "
        "loop (`cv2.solvePnP` SQPNP and `solvePnPRefineLM`) takes "
        + (f"{duration(1e-6 * cpu_peer)} of CPU per problem." if cpu_peer else "-")
    )
    return (
        note
        + "\n\n"
        + table(header, out_rows)
        + "\n\n"
        + caption(d, *names, command=_run_command(d, "scale"))
    )


def scale_cache(results: Path) -> str:
    d, name = load(results, "scale.json", "scale_quick.json")
    target = d["cache"].get("target_s")
    rows = []
    for r in d["cache"]["rows"]:
        if r["kind"] == "single":
            what = f"`solve`, n = {r['config'][0]} ({r['config'][1]})"
        else:
            what = f"`solve_pnp_batch`, B = {r['config'][0]:,}, `chunk_size={r['config'][1]}`"
        split = (
            f" ({duration(r['cached_lower_s'])} + {duration(r['cached_xla_s'])})"
            if "cached_lower_s" in r
            else ""
        )
        rows.append(
            (
                what,
                duration(r["cold_compile_s"]),
                duration(r["cached_compile_s"]) + split,
                verdict(r["cached_compile_s"], target, False) if target else "",
            )
        )
    header = (
        "program",
        "cold compile",
        "with the persistent cache (trace + XLA)",
        f"target <= {target:g} s" if target else "target",
    )
    return table(header, rows) + "\n\n" + caption(d, name, command=_run_command(d, "scale"))


# ----------------------------------------------------------------------------- accuracy
