"""MkDocs hooks (`hooks:` in `mkdocs.yml`): before every build, write the benchmark tables
and plots of `benchmarks/results/` into `docs/generated/` (`tables.py`), where the pages
include them, so that the site always shows the saved results; and copy the notebooks
into `docs/generated/notebooks/`, where the build executes them into pages."""

from __future__ import annotations

import importlib.util
from pathlib import Path

_TABLES = Path(__file__).resolve().parent / "tables.py"


def _tables_module():
    spec = importlib.util.spec_from_file_location("jaxpose_docs_tables", _TABLES)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def on_pre_build(config, **kwargs) -> None:
    tables = _tables_module()
    root = Path(config["config_file_path"]).resolve().parent
    generated = Path(config["docs_dir"]) / "generated"
    tables.write(root / "benchmarks" / "results", generated)
    # The notebooks, copied where the site's notebook plugin (mkdocs-jupyter) executes
    # them and shows their outputs: a notebook that fails fails the build.
    pages = generated / "notebooks"
    pages.mkdir(parents=True, exist_ok=True)
    for notebook in sorted((root / "notebooks").glob("*.ipynb")):
        target = pages / notebook.name
        data = notebook.read_bytes()
        if not target.is_file() or target.read_bytes() != data:
            target.write_bytes(data)
