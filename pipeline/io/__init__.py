"""Storage: Parquet tables (with explicit, documented schemas), Zarr videos, imports and exports."""
