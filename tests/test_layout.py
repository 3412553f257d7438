"""The package's layout: imports point down the layers, no import cycle, no module too long.

The graph is read from the source (`ast`), every import counted: module level, inside
functions (lazy imports) and under `TYPE_CHECKING` alike.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxpose"

# Low to high: a module may import from its own layer or a lower one.
LAYERS = ("geometry", "solvers", "strategy", "api", "features", "apps", "viz", "cli")
MAX_LINES = 600


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> list[str]:
    """The `jaxpose` modules an import statement loads (package `__init__`s included)."""
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    names = [target] + [f"{target}.{alias.name}" for alias in node.names]
    return names


def import_graph() -> dict[str, set[str]]:
    modules = _modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_package = path.name == "__init__.py"
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                targets = _resolve(name, is_package, node)
            elif isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                continue
            for target in targets:
                if not target.startswith("jaxpose"):
                    continue
                # (`from a.b import c` also runs the `__init__` of `a`: implied, not an
                # edge; `c` is an edge when it is a module.)
                if target in modules and target != name:
                    graph[name].add(target)
    return graph


def _ancestors(module: str) -> set[str]:
    parts = module.split(".")
    return {".".join(parts[:k]) for k in range(1, len(parts))}


def _layer(module: str) -> int | None:
    parts = module.split(".")
    if len(parts) < 2:
        return None  # the top-level package: above every layer
    return LAYERS.index(parts[1]) if parts[1] in LAYERS else None


def test_every_subpackage_is_a_known_layer():
    subpackages = {p.parent.name for p in PACKAGE.glob("*/__init__.py")}
    assert subpackages == set(LAYERS)
    assert {p.name for p in PACKAGE.glob("*.py")} == {"__init__.py"}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of `graph` (its modules in order, the first repeated last), or None.

    Importing a submodule runs its packages' `__init__`s first: an edge from a module to
    one of its own packages is implied by Python, so it is skipped unless that package
    imports the module back.
    """
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt in _ancestors(node) and node not in graph.get(nxt, ()):
                continue
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for module in sorted(graph):
        if module not in state and (cycle := visit(module)):
            return cycle
    return None


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_imports_point_down():
    wrong = []
    for module, targets in import_graph().items():
        own = _layer(module)
        if own is None:
            continue
        for target in targets:
            layer = _layer(target)
            if target == "jaxpose" or (layer is not None and layer > own):
                wrong.append(f"{module} -> {target}")
    assert not wrong, "imports pointing up: " + ", ".join(sorted(wrong))


def test_no_module_too_long():
    long = {
        name: n
        for name, path in _modules().items()
        if (n := len(path.read_text().splitlines())) > MAX_LINES
    }
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def test_cycle_detection_works():
    """The checkers themselves, on hand-made graphs and on the real one."""
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    # A module importing its own package is fine unless the package imports it back.
    assert find_cycle({"p.m": {"p"}, "p": set()}) is None
    assert find_cycle({"p.m": {"p"}, "p": {"p.m"}}) == ["p", "p.m", "p"]
    graph = import_graph()
    assert "jaxpose.geometry._camera" in graph["jaxpose.geometry"]
    assert "jaxpose.geometry._camera" in graph["jaxpose.solvers._p3p"]


def test_the_api_uses_the_lower_layers_public_names():
    """The entry points (`jaxpose.api`) are adapters: they import the geometry, solvers
    and strategy layers through their packages' public names only, never a private
    module of theirs."""
    lower = {"jaxpose." + layer for layer in LAYERS[: LAYERS.index("api")]}
    private = []
    for module, targets in import_graph().items():
        if _layer(module) != LAYERS.index("api"):
            continue
        for target in targets:
            if any(target.startswith(package + ".") for package in lower):
                private.append(f"{module} -> {target}")
    assert not private, "private imports from below: " + ", ".join(sorted(private))
