"""The documentation's layout check (`docs/scripts/check_layout.py`, run by `make test`
after its docs build) on two small pages in headless Chromium: a code block and a table
wider than the content column are found, a page that fits passes, and every page gets a
screenshot. Skipped where no Chromium is installed. The check runs in a process of its
own, as `make test` runs it: it starts the browser with a `preexec_fn` (a fork), which
JAX, already running in a test worker, warns against."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "docs" / "scripts" / "check_layout.py"


def _module():
    spec = importlib.util.spec_from_file_location("check_layout", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


check_layout = _module()
pytestmark = pytest.mark.skipif(
    check_layout.find_browser(None) is None, reason="no Chromium installed"
)

PAGE = """<!doctype html><html><head><style>
body {{ margin: 0; font-family: sans-serif; }}
.md-content {{ width: 700px; }}
.md-content__inner {{ margin: 0 16px; }}
pre > code {{ display: block; overflow: auto; }}
.scroll {{ overflow-x: auto; }}
</style></head><body><div class="md-content"><div class="md-content__inner">
<h1>Page</h1>{body}</div></div></body></html>"""

WIDE = """<h2>Start here</h2><pre><code>{line}</code></pre>
<h2>Figures</h2><div class="scroll"><table><tr>{cells}</tr></table></div>""".format(
    line="make demo  # " + "a comment that runs on " * 8,
    cells="<th>a_long_column_name</th>" * 12,
)
NARROW = "<h2>Start here</h2><pre><code>make demo  # short</code></pre>"


def _check(*args: str) -> tuple[int, str]:
    """`check_layout.py *args` in a fresh process: its exit code and output."""
    run = subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=300
    )
    return run.returncode, run.stdout


def test_wide_blocks_are_found_and_every_page_is_screenshot(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    (site / "index.html").write_text(PAGE.format(body=NARROW))
    (site / "wide.html").write_text(PAGE.format(body=WIDE))
    shots = tmp_path / "shots"
    code, out = _check(str(site), str(shots))
    assert code == 1, out
    lines = [line for line in out.splitlines() if line.startswith("wide.html:")]
    assert len(lines) == 2, out
    assert any("code block" in line and '"Start here"' in line for line in lines), out
    assert any(line.startswith("wide.html: table") and '"Figures"' in line for line in lines)
    assert not any(line.startswith("index.html:") for line in out.splitlines()), out
    assert sorted(p.name for p in shots.iterdir()) == ["index.png", "wide.png"]
    assert (shots / "wide.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_page_that_fits_passes(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    (site / "index.html").write_text(PAGE.format(body=NARROW))
    code, out = _check(str(site), str(tmp_path / "shots"))
    assert code == 0, out
