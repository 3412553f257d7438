"""The table of OpenCV's own PnP test cases run on `cv2` and on jaxpose
(`benchmarks/opencv_cases.py`), for the documentation (`tables.py`)."""

from __future__ import annotations

from pathlib import Path

from tables_format import caption, load, share, table


def _cell(r: dict) -> str:
    verdict = "pass" if r["passed"] else "**fail**"
    return f"{verdict} ({share(r['rate'], 0)})" if "rate" in r else verdict


def opencv_cases(results: Path) -> str:
    """One row per case: whether `cv2` and jaxpose pass it (with the share of trials
    within OpenCV's thresholds for an accuracy case)."""
    d, name = load(results, "opencv_cases.json")
    rows = [(r["case"], _cell(r["cv2"]), _cell(r["jaxpose"])) for r in d["rows"]]
    out = table(("case", "cv2", "jaxpose"), rows)
    every = "yes" if d["jaxpose_passes_every_cv2_pass"] else "**no**"
    out += (
        f"\n\n*{d['trials']} trials per accuracy case (pass: at least "
        f"{share(d['pass_rate'], 0)} within the thresholds, OpenCV's rule); jaxpose passes "
        f"every case cv2 passes: {every}.*"
    )
    ippe = d.get("ippe")
    if ippe:
        out += (
            f"\n\n*`solve_pnp_generic` on {ippe['problems']:,} planar problems: its poses "
            f"hold IPPE's two refined to their local minima, and are all local minima, in "
            f"{share(ippe['same_as_ippe'], 1)} of them ({share(ippe['two_minima'], 0)} "
            f"have two or more distinct minima).*"
        )
    return out + "\n\n" + caption(d, name, command="python benchmarks/opencv_cases.py")
