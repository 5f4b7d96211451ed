"""The generated files in schemas/ match the code (regenerate with `mvpd schemas`)."""

from pathlib import Path

from pipeline.io.schema_export import rendered_schemas

SCHEMAS = Path(__file__).resolve().parents[1] / "schemas"


def test_schemas_folder_is_in_sync_with_the_code():
    stale = [name for name, text in rendered_schemas().items()
             if not (SCHEMAS / name).is_file() or (SCHEMAS / name).read_text() != text]
    assert not stale, f"schemas/ is out of date for {stale}; run `mvpd schemas`"


def test_every_table_column_is_documented():
    import json

    for path in (SCHEMAS / "tables").glob("*.json"):
        document = json.loads(path.read_text())
        undocumented = [c["name"] for c in document["columns"] if not c["description"]]
        assert not undocumented, f"{path.name}: columns without a description: {undocumented}"
