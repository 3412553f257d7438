"""The tables and the plot of `benchmarks/scale.py`, from its result dict alone (so that a
saved `scale*.json` can be shown again)."""

from __future__ import annotations

from pathlib import Path


def _mb(x) -> str:
    return "-" if x is None else f"{x / 2**20:.2f} MB"


def _ms(x) -> str:
    return "-" if x is None else (f"{1e3 * x:.2f} ms" if x < 10 else f"{x:.1f} s")


def _rss(r: dict) -> str:
    run = r.get("run_rss_growth_mb")
    return f"{'-' if run is None else f'{run:.1f}'} MB (+{r['rss_growth_mb']:.0f})"


def print_tables(res: dict, console) -> None:
    from rich.table import Table

    t = Table(title="One problem vs n (jit(jaxpose.solve), float64, 1 px)")
    cols = ("n", "strategy", "triplets", "warm (CPU)", "compile (trace+XLA)", "XLA peak")
    cols += ("RSS run (+compile)",)
    for c in cols + ("error px",):
        t.add_column(c, justify="left" if c == "strategy" else "right")
    for r in res["n"]["rows"]:
        if "skipped" in r:
            proj = r.get("projected_warm_s")
            t.add_row(
                str(r["n"]),
                r["strategy"],
                str(r["triplets_exhaustive"]),
                f"~{_ms(proj)} (projected)" if proj else "-",
                "skipped",
                "",
                "",
                "",
            )
            continue
        if "failed" in r:
            t.add_row(str(r["n"]), r["strategy"], "", "failed", r["failed"][:60], "", "", "")
            continue
        t.add_row(
            str(r["n"]),
            r["strategy"],
            f"{r['triplets_solved']} of {r['triplets_exhaustive']}",
            f"{_ms(r['warm_s'])} ({_ms(r['warm_cpu_s'])})",
            f"{r['compile_s']:.1f} s ({r['lower_s']:.1f}+{r['xla_compile_s']:.1f})",
            _mb(r["memory"]["peak_bytes"]),
            _rss(r),
            f"{r['error_px']:.4f}",
        )
    console.print(t)
    console.print(res["n"]["switch"]["text"])

    b = Table(title="Batches: solve_pnp_batch(n = 16, triplet_budget = 8) vs OpenCV loop")
    cols = ("B", "chunk", "time", "per problem", "OpenCV", "jaxpose is", "CPU: is")
    for c in cols + ("first call", "XLA peak / chunk", "RSS run (+compile)"):
        b.add_column(c, justify="right")
    for r in res["batch"]["rows"]:
        if "failed" in r:
            b.add_row(str(r["B"]), str(r["chunk_size"]), "failed", r["failed"][:60])
            continue
        b.add_row(
            str(r["B"]),
            str(r["chunk"]),
            _ms(r["warm_s"]),
            f"{r['per_problem_us']:.0f} us",
            f"{r['opencv_per_problem_us']:.0f} us",
            f"{r['vs_opencv']:.2f}x",
            f"{r['per_problem_cpu_us']:.0f}/{r['opencv_per_problem_cpu_us']:.0f} us "
            f"{r['vs_opencv_cpu']:.2f}x",
            f"{r['first_call_s']:.1f} s",
            _mb(r["memory"]["peak_bytes"]),
            _rss(r),
        )
    console.print(b)
    c = res["cache"]
    if c.get("rows"):
        ct = Table(
            title=f"Compile: cold vs persistent cache (target <= {res['targets']['compile_s']:g} s)"
        )
        for col in ("config", "cold", "cached", "of which trace+lower (cached)", "RSS cold/cached"):
            ct.add_column(col, justify="right")
        for r in c["rows"]:
            if "failed" in r:
                ct.add_row(str(r["config"]), "failed", r["failed"][:60], "", "")
                continue
            ct.add_row(
                f"{r['kind']} {r['config']}",
                f"{r['cold_compile_s']:.1f} s",
                f"{r['cached_compile_s']:.1f} s",
                f"{r['cached_lower_s']:.1f} s" if "cached_lower_s" in r else "-",
                f"{r['cold_rss_growth_mb']:.0f} / {r['cached_rss_growth_mb']:.0f} MB",
            )
        console.print(ct)
    else:
        console.print(f"compile cache: {c.get('skipped', 'no rows')}")


def _plot_hollow(a, xs: list, ys: list, style: str, label: str) -> None:
    """A second look at the first series of `a` (projected, or CPU time): same colour,
    hollow markers."""
    a.loglog(xs, ys, style, mfc="none", color="C0", label=label)


def _plot_batch(ax, rows: list[dict], what: str, styles: tuple[str, str, str], **kw) -> None:
    """One batch configuration (`what`) against B: its time per problem on `ax[0]`, its
    XLA peak and its RSS growth while running on `ax[1]`."""
    bs = [r["B"] for r in rows]
    ax[0].loglog(bs, [r["per_problem_us"] for r in rows], styles[0], **kw, label=f"jaxpose, {what}")
    peak = [r["memory"]["peak_bytes"] / 2**20 for r in rows]
    ax[1].loglog(bs, peak, styles[1], **kw, label=f"XLA peak, {what}")
    rss = [max(r["run_rss_growth_mb"] or 0, 1e-2) for r in rows]
    ax[1].loglog(bs, rss, styles[2], **kw, label=f"RSS growth while running, {what}")


def plot(res: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sample = res["n"]["switch"]["max_triplets"]
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    rows = [r for r in res["n"]["rows"] if "warm_s" in r]
    for s, style in (("exhaustive", "o-"), ("sampled", "s-"), ("budget8", "^-")):
        rs = sorted((r for r in rows if r["strategy"] == s), key=lambda r: r["n"])
        if s == "sampled":  # below 2000 triplets the sample is the exhaustive set
            rs = sorted(
                [
                    r
                    for r in rows
                    if r["strategy"] == "exhaustive" and r["triplets_exhaustive"] <= sample
                ]
                + rs,
                key=lambda r: r["n"],
            )
        if not rs:
            continue
        ns = [r["n"] for r in rs]
        label = f"sampled ({sample}; = exhaustive below)" if s == "sampled" else s
        ax[0, 0].loglog(ns, [r["warm_s"] for r in rs], style, label=label)
        ax[0, 1].loglog(ns, [r["memory"]["peak_bytes"] / 2**20 for r in rs], style, label=label)
    proj = [r for r in res["n"]["rows"] if r.get("projected_warm_s")]
    if proj:
        xs, ys = [r["n"] for r in proj], [r["projected_warm_s"] for r in proj]
        _plot_hollow(ax[0, 0], xs, ys, "o", "exhaustive (projected)")
    sw = res["n"]["switch"]["library_switch_n"]
    for a in ax[0]:
        a.axvline(sw, color="grey", ls=":", lw=1)
        a.set_xlabel("matches n")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    ax[0, 0].set_ylabel("warm time, one problem (s)")
    ax[0, 1].set_ylabel("XLA peak memory (MB)")
    ax[0, 0].set_title(f"dotted: library switch to a {sample}-sample (n = {sw})", fontsize=9)
    brows = [r for r in res["batch"]["rows"] if "warm_s" in r]
    chunks = sorted({r["chunk"] for r in brows if r["chunk_size"] is not None})
    one = sorted((r for r in brows if r["chunk_size"] is None), key=lambda r: r["B"])
    if one:
        _plot_batch(ax[1], one, "one call", ("o-", "o-", "o--"))
    for i, c in enumerate(chunks):
        rs = sorted((r for r in brows if r["chunk"] == c and r["chunk_size"]), key=lambda r: r["B"])
        _plot_batch(ax[1], rs, f"chunks of {c}", ("s", "s", "x"), color=f"C{i + 2}")
    if one:
        xs, ys = [r["B"] for r in one], [r["per_problem_cpu_us"] for r in one]
        _plot_hollow(ax[1, 0], xs, ys, "o:", "jaxpose, one call, CPU time")
    cv = res["batch"]["opencv_per_problem_us"]
    ax[1, 0].axhline(cv, color="k", ls="--", lw=1, label="OpenCV SQPnP + RefineLM loop")
    ax[1, 0].axhline(
        res["batch"]["opencv_per_problem_cpu_us"], color="k", ls=":", lw=1, label="OpenCV, CPU time"
    )
    ax[1, 0].set_ylabel("time per problem (us): wall, and CPU (dotted)")
    ax[1, 1].set_ylabel("memory (MB)")
    for a in ax[1]:
        a.set_xlabel("problems in the batch B (n = 16, triplet_budget = 8)")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=7)
    from matplotlib.ticker import ScalarFormatter

    for a in ax.flat:
        a.xaxis.set_major_formatter(ScalarFormatter())
        a.xaxis.set_minor_formatter(plt.NullFormatter())
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
