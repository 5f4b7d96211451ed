"""Layers point down: nothing in `pipeline/runtime/` imports the layers above it (io, cli, the stages)."""

from __future__ import annotations

import ast
from pathlib import Path

RUNTIME = Path(__file__).resolve().parents[2] / "pipeline" / "runtime"
# Above the runtime: table I/O's public face and readers, the CLI, and every stage area.
ABOVE = ("pipeline.io", "pipeline.cli", "pipeline.scenes", "pipeline.plan", "pipeline.render", "pipeline.split",
         "pipeline.evaluate", "pipeline.models", "pipeline.overview")


def imported_modules(path: Path) -> set[str]:
    """Every module an `import` or `from ... import` names in a file (at any depth, lazy imports included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return found


def test_no_runtime_module_imports_a_layer_above_it():
    climbing = {f"{path.name}: {module}" for path in sorted(RUNTIME.glob("*.py")) for module in imported_modules(path)
                if any(module == above or module.startswith(above + ".") for above in ABOVE)}
    assert not climbing, f"runtime modules import layers above them: {sorted(climbing)}"


def test_the_check_sees_a_lazy_import(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from pipeline.io.tables import read_dataset\n")
    assert "pipeline.io.tables" in imported_modules(module)


# ------------------------------------------------------------------ the storage room, and no circles
PACKAGE = RUNTIME.parent
STORE = PACKAGE / "store"


def module_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the package modules it imports (lazy imports included; `if TYPE_CHECKING:` blocks and the
    root package, which every module's import runs first anyway, left out)."""
    paths = {".".join(p.relative_to(package.parent).with_suffix("").parts).removesuffix(".__init__"): p
             for p in package.rglob("*.py")}
    graph = {}
    for name, path in paths.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
                       for n in ast.walk(node)}
        imported = set()
        for node in ast.walk(tree):
            if id(node) not in typing_only and isinstance(node, (ast.Import, ast.ImportFrom)):
                imported |= imported_names(node)
        graph[name] = {m for m in imported if m in paths and m not in (name, "pipeline")}
    return graph


def imported_names(node: ast.Import | ast.ImportFrom) -> set[str]:
    if isinstance(node, ast.Import):
        return {alias.name for alias in node.names}
    if not node.module or node.level:
        return set()
    return {node.module} | {f"{node.module}.{alias.name}" for alias in node.names}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of `graph`: its strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        for other in sorted(graph[module]):
            if other not in index:
                visit(other)
                low[module] = min(low[module], low[other])
            elif other in stack:
                low[module] = min(low[module], index[other])
        if low[module] == index[module]:
            component = []
            while not component or component[-1] != module:
                component.append(stack.pop())
            if len(component) > 1:
                found.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return found


def test_no_module_of_the_package_is_in_an_import_circle():
    assert circles(module_graph()) == []


def test_the_circle_check_finds_a_circle():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_store_imports_nothing_of_the_runtime_or_above():
    climbing = {f"{path.name}: {module}" for path in sorted(STORE.glob("*.py")) for module in imported_modules(path)
                if any(module == above or module.startswith(above + ".")
                       for above in ("pipeline.runtime", "pipeline.stages", *ABOVE))}
    assert not climbing, f"store modules import layers above them: {sorted(climbing)}"


def test_the_runtime_room_stays_small():
    lines = sum(len(path.read_text(encoding="utf-8").splitlines()) for path in RUNTIME.glob("*.py"))
    assert lines < 1500, f"pipeline/runtime/ has {lines} lines; storage belongs in pipeline/store/"
