"""The benchmarks import each other's helpers by name; a name one of them drops must not go unnoticed until a
long benchmark run stops at its import (bench_render --vs-mitsuba once did, on bench_light's rewrite)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def top_level_names(path: Path) -> set[str]:
    """Names a module defines at its top level: functions, classes, assignments and imports."""
    names: set[str] = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((alias.asname or alias.name).split(".")[0] for alias in node.names)
    return names


def sibling_imports() -> list[tuple[str, str, str]]:
    """(importing file, sibling module, name) for every `from <sibling benchmark> import name`, at any depth."""
    siblings = {path.stem for path in BENCHMARKS.glob("*.py")}
    found = []
    for path in sorted(BENCHMARKS.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module in siblings:
                found.extend((path.name, node.module, alias.name) for alias in node.names)
    return found


def test_the_benchmarks_import_one_another():
    assert {module for _, module, _ in sibling_imports()} >= {"bench_light", "bench_render"}


@pytest.mark.parametrize("importer, module, name", sibling_imports())
def test_every_name_a_benchmark_imports_from_a_sibling_exists(importer, module, name):
    assert name in top_level_names(BENCHMARKS / f"{module}.py"), f"{importer} imports {name!r} that {module}.py lacks"
