"""Writes the generated data contracts into `schemas/`: config JSON Schemas and Parquet table schemas."""

from __future__ import annotations

import json
from pathlib import Path


from pipeline.config import json_schemas
from pipeline.io.tables import TableSpec, all_tables


def table_document(spec: TableSpec) -> dict:
    """A JSON description of a Parquet dataset: what a row is and each column's type and meaning."""
    return {
        "dataset": spec.name,
        "version": spec.version,
        "row": spec.row,
        "columns": [
            {"name": f.name, "type": str(f.type), "nullable": f.nullable,
             "description": (f.metadata or {}).get(b"description", b"").decode()}
            for f in spec.schema
        ],
    }


def rendered_schemas() -> dict[str, str]:
    """Relative path -> file text of every generated schema file."""
    files = {name: json.dumps(schema, indent=2, sort_keys=True) + "\n" for name, schema in json_schemas().items()}
    for name, spec in all_tables().items():
        files[f"tables/{name}.json"] = json.dumps(table_document(spec), indent=2) + "\n"
    return files


def write_schemas(out: Path) -> list[Path]:
    """Write every generated schema file below `out`; returns the paths written."""
    written = []
    for relative, text in rendered_schemas().items():
        path = out / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


__all__ = ["rendered_schemas", "table_document", "write_schemas"]
