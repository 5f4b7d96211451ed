"""Layers point down inside `pipeline/scenes`: no module imports (even lazily) one that imports it back."""

from __future__ import annotations

import ast
from pathlib import Path

import pipeline.scenes

PACKAGE = Path(pipeline.scenes.__file__).parent


def _scene_imports(path: Path) -> set[str]:
    """`pipeline.scenes.*` modules a file imports anywhere (module level or inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pipeline.scenes."):
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("pipeline.scenes."))
    return found


def _graph() -> dict[str, set[str]]:
    modules = {}
    for path in PACKAGE.rglob("*.py"):
        name = "pipeline." + ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__")
        modules[name] = _scene_imports(path)
    return modules


def test_scene_module_is_the_bottom_layer() -> None:
    assert _graph()["pipeline.scenes.scene"] <= {"pipeline.scenes.categories"}


def test_no_import_climbs_back() -> None:
    graph = _graph()

    def reaches(start: str, target: str, seen: set[str]) -> bool:
        for child in graph.get(start, ()):
            if child == target or (child not in seen and (seen.add(child) or reaches(child, target, seen))):
                return True
        return False

    cycles = sorted(f"{a} -> {b}" for a, imports in graph.items() for b in imports if reaches(b, a, set()))
    assert not cycles, f"imports that climb back: {cycles}"
