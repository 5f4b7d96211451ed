"""Public face of the table registry and part I/O, kept so `from pipeline.io.tables import ...` still works.

The implementation lives below the runtime in `pipeline.runtime.tables` (the runtime's status table uses
it, so it cannot sit above the runtime); new code imports from there.
"""

from pipeline.runtime.tables import (  # noqa: F401 - re-exported names
    TableSpec,
    all_tables,
    column,
    damaged_parts,
    dataset_parts,
    read_dataset,
    register,
    spec,
    to_table,
    write_part,
)

__all__ = ["TableSpec", "all_tables", "column", "damaged_parts", "dataset_parts", "read_dataset", "register", "spec",
           "to_table", "write_part"]
