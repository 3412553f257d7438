"""Matplotlib figures of the paper's experiment: Figures 3 and 4 (histogram and cumulative
histogram of the triplets by pose error, one curve per method)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..apps._experiment import METHOD_NAMES, ExperimentResult
from ._rerun_common import METHOD_LABELS

__all__ = ["write_figures"]


def write_figures(result: ExperimentResult, out_dir: Path) -> list[Path]:
    """Figures 3 and 4: histogram and cumulative histogram of samples versus pose error,
    one curve per method, as `figure3_histogram.png` and `figure4_cumulative.png`.

    **Arguments:**
    - `result`: `run_experiment`'s `ExperimentResult`.
    - `out_dir`: the folder to write to (created if needed).

    **Returns:** the PNG paths.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    used = result.used
    hi = float(np.percentile(np.concatenate([v[used] for v in result.pose_error.values()]), 99))
    bins = np.linspace(0.0, max(hi, result.optimum * 2), 60)
    paths = []
    for name, cumulative in (("figure3_histogram.png", False), ("figure4_cumulative.png", True)):
        fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
        drawn: dict[str, np.ndarray] = {}
        for k, m in enumerate(METHOD_NAMES):
            e = np.clip(result.pose_error[m][used], bins[0], bins[-1])
            counts, edges = np.histogram(e, bins=bins)
            share = 100.0 * counts / max(len(e), 1)
            y = np.cumsum(share) if cumulative else share
            # Methods whose curves coincide stay visible: each drawn thinner than the
            # one below it, in its own dash, and the legend says which it covers.
            same = [METHOD_LABELS[o] for o, c in drawn.items() if np.array_equal(c, counts)]
            label = METHOD_LABELS[m] + (f" (same curve as {', '.join(same)})" if same else "")
            drawn[m] = counts
            ax.step(
                edges[1:],
                y,
                where="pre",
                label=label,
                linewidth=3.2 - 0.8 * k,
                linestyle=("-", "--", "-.", ":")[k % 4],
            )
        ax.set_xlabel("pose error (mm)")
        ax.set_ylabel("cumulative samples (%)" if cumulative else "samples (%)")
        title = "Figure 4: cumulative histogram" if cumulative else "Figure 3: histogram"
        ax.set_title(f"{title} ({int(np.sum(used))} triplets)")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path)
        plt.close(fig)
        paths.append(path)
    return paths
