"""MkDocs hooks (`hooks:` in `mkdocs.yml`): before every build, write the benchmark tables
and plots of `benchmarks/results/` into `docs/generated/` (`tables.py`), where the pages
include them, so that the site always shows the saved results."""

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
    tables.write(root / "benchmarks" / "results", Path(config["docs_dir"]) / "generated")
