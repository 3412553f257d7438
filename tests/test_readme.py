"""The README's code runs as written: every ```python block, each in a fresh namespace and
a fresh working folder (as a newcomer pastes it), and its generated tables are those the
saved results give."""

import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
BLOCKS = re.findall(r"^```python\n(.*?)^```", README, flags=re.S | re.M)


def test_the_readme_has_code_to_run():
    assert len(BLOCKS) >= 4


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_block_runs(index, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(BLOCKS[index], f"README.md, python block {index + 1}", "exec"), {})


def test_readme_tables_are_the_saved_results():
    sys.path.insert(0, str(ROOT / "docs" / "scripts"))
    import tables

    assert tables.readme_with_tables(README, tables.build()) == README
