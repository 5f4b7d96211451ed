"""Public face of the run's tables: the registry (`pipeline.store.tables`) and marker-trusted reading
(`pipeline.store.datasets`, each taking an opened RunFolder); import from here."""

from pipeline.store.datasets import (  # noqa: F401 - re-exported names
    damage_line,
    damaged_parts,
    dataset_parts,
    read_dataset,
    trusted_parts,
    trusted_parts_of,
)
from pipeline.store.tables import TableSpec, all_tables, column, register, spec, to_table, write_part  # noqa: F401

__all__ = ["TableSpec", "all_tables", "column", "damage_line", "damaged_parts", "dataset_parts", "read_dataset",
           "register", "spec", "to_table", "trusted_parts", "trusted_parts_of", "write_part"]
