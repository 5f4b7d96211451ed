"""The render stage: CPU ray casting (Embree 4 packets), lighting, depth sensor models, Zarr + Parquet outputs."""
