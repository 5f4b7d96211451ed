"""Public face of `pipeline.runtime.tables` (moved below the runtime, whose status table uses it); import from there."""

from pipeline.runtime.tables import (  # noqa: F401 - re-exported names
    TableSpec,
    all_tables,
    column,
    damage_line,
    damaged_parts,
    dataset_parts,
    read_dataset,
    read_part,
    register,
    spec,
    to_table,
    trusted_parts,
    trusted_parts_of,
    write_part,
)

__all__ = ["TableSpec", "all_tables", "column", "damage_line", "damaged_parts", "dataset_parts", "read_dataset", "read_part",
           "register", "spec", "to_table", "trusted_parts", "trusted_parts_of", "write_part"]
