"""The README and the documentation pages: the README stays short, every relative link
points to a file that exists, and the benchmark tables are generated from the saved
results (`docs/scripts/tables.py`). `make test` also builds the site with
`mkdocs build --strict`, which checks links, anchors and the API reference."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README_MAX_LINES = 250

_FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
_CODE = re.compile(r"`[^`\n]*`")
_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_SNIPPET = re.compile(r"^\s*--8<--\s+\"([^\"]+)\"", re.M)


def _tables():
    spec = importlib.util.spec_from_file_location("docs_tables", DOCS / "scripts" / "tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def tables():
    return _tables()


def _pages() -> list[Path]:
    return [ROOT / "README.md"] + sorted(
        p for p in DOCS.rglob("*.md") if "generated" not in p.relative_to(DOCS).parts
    )


def _links(text: str) -> list[str]:
    """Link targets of a Markdown text, code blocks and inline code left out."""
    text = _CODE.sub("", _FENCE.sub("", text))
    return _LINK.findall(text)


def _is_relative(target: str) -> bool:
    return not (re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith(("#", "/")))


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"


def test_link_finder():
    text = "a [b](c.md#x) `[d](e.md)` ![f](g/h.png)\n```\n[i](j.md)\n```\n[k](https://l)"
    assert _links(text) == ["c.md#x", "g/h.png", "https://l"]
    assert [t for t in _links(text) if _is_relative(t)] == ["c.md#x", "g/h.png"]


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_to_existing_files(page, tables):
    generated = set(tables.outputs())
    missing = []
    for target in _links(page.read_text()):
        if not _is_relative(target):
            continue
        path = target.split("#", 1)[0]
        if not path:
            continue
        resolved = (page.parent / path).resolve()
        if resolved.is_relative_to(DOCS / "generated"):
            ok = resolved.relative_to(DOCS / "generated").as_posix() in generated
        else:
            ok = resolved.exists()
        if not ok:
            missing.append(target)
    assert not missing, f"{page.relative_to(ROOT)}: links to missing files {missing}"


def test_every_included_table_is_generated(tables):
    generated = set(tables.outputs())
    for page in _pages():
        for name in _SNIPPET.findall(page.read_text()):
            assert name in generated, f"{page.relative_to(ROOT)} includes {name!r}"


def test_tables_are_generated_from_the_saved_results(tables, tmp_path):
    built = tables.build(tables.RESULTS)
    assert set(built) == set(tables.TABLES)
    for name, text in built.items():
        assert "No saved result" not in text, (name, text)
        rows = [line for line in text.splitlines() if line.startswith("| ")]
        assert len(rows) >= 3, (name, text)  # a header, its rule, at least one row
        assert "Source: `benchmarks/results/" in text or name in tables.FROM_SOURCE, name
    changed = tables.write(tables.RESULTS, tmp_path)
    assert {p.name for p in changed} == {p.name for p in tmp_path.iterdir()}
    assert {f"{name}.md" for name in tables.TABLES} <= {p.name for p in tmp_path.iterdir()}
    assert tables.write(tables.RESULTS, tmp_path) == []  # unchanged: nothing rewritten


def test_missing_results_give_a_note_not_an_error(tables, tmp_path):
    built = tables.build(tmp_path)
    for name, text in built.items():
        assert ("No saved result" in text) != (name in tables.FROM_SOURCE), (name, text)


def test_every_layer_has_an_api_page():
    layers = sorted(
        p.parent.name
        for p in (ROOT / "jaxpose").glob("*/__init__.py")
        if p.parent.name != "cli"  # the command line is documented in docs/cli.md
    )
    assert layers, "no subpackages found"
    for layer in layers:
        page = DOCS / "api" / f"{layer}.md"
        assert page.is_file(), f"no API page for jaxpose.{layer}"
        assert f"::: jaxpose.{layer}\n" in page.read_text(), page
    assert "::: jaxpose\n" in (DOCS / "api" / "index.md").read_text()


def test_summary_tables_show_whole_first_sentences():
    """The API reference's summary tables take a docstring's first line; the docs'
    griffe extension puts the whole first sentence there (the paragraph renders alike)."""
    sys.path.insert(0, str(ROOT / "docs" / "scripts"))
    from griffe_summaries import first_sentence_first

    text = "`solve` for a batch: the same\nanswers as `x.y`. Then more\ntext.\n\nBody."
    assert first_sentence_first(text) == (
        "`solve` for a batch: the same answers as `x.y`.\nThen more text.\n\nBody."
    )
    assert first_sentence_first("One line.\n\nMore.") == "One line.\n\nMore."
    import jaxpose

    first = first_sentence_first(jaxpose.solve_many.__doc__.strip()).split("\n")[0]
    assert first.endswith("computed batch-first.")
