"""The shape of the repository: the product (``nbv_prob_cnn/``) imports no study, no module of the
product takes part in an import circle, and every study is listed in ``studies/README.md``."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGE = REPO / "nbv_prob_cnn"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_names(path: Path) -> list[str]:
    """Every module name an import statement of ``path`` names, wherever it stands (relative
    imports resolved)."""
    tree = ast.parse(path.read_text(), str(path))
    nodes = list(ast.walk(tree))
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    names = []
    for node in nodes:
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            names.append(base)
            names += [f"{base}.{alias.name}" for alias in node.names]
    return names


def test_the_product_imports_no_study() -> None:
    offenders = [
        f"{path.relative_to(REPO)} imports {name}"
        for path in sorted(PACKAGE.rglob("*.py"))
        for name in imported_names(path)
        if name == "studies" or name.startswith("studies.")
    ]
    assert not offenders, "the product must not import studies/:\n" + "\n".join(offenders)


def import_graph() -> dict[str, set[str]]:
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    return {name: {m for m in imported_names(path) if m in modules and m != name} for name, path in modules.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_cycle_finder_by_hand() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle_between_modules_of_the_product() -> None:
    """Every import counts, those inside functions and under ``TYPE_CHECKING`` too: a circle of
    lazy imports is still two modules that need each other."""
    graph = import_graph()
    # a package's __init__ importing its own submodules, and a submodule importing a sibling
    # through the package, is the usual re-export pattern, not a circle of two modules' code
    for name in graph:
        if name.count(".") >= 1:
            parent = name.rsplit(".", 1)[0]
            if parent in graph and name in graph[parent]:
                graph[name].discard(parent)
    assert cycles(graph) == []


def test_every_study_is_in_the_studies_readme() -> None:
    readme = (REPO / "studies" / "README.md").read_text()
    names = [p.stem for p in (REPO / "studies").glob("*.py") if not p.stem.startswith("_")]
    assert len(names) >= 10
    missing = [n for n in names if f"`{n}`" not in readme]
    assert not missing, f"studies/README.md has no row for {missing}"


#: The handbook's limit on a module of the product (lines): a module that grows past it is split.
MAX_MODULE_LINES = 600


def test_no_module_of_the_product_is_above_600_lines() -> None:
    long = {
        str(path.relative_to(REPO)): n
        for path in sorted(PACKAGE.rglob("*.py"))
        if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES
    }
    assert not long, f"modules above {MAX_MODULE_LINES} lines (split them by what they do): {long}"
