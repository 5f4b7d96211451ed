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
