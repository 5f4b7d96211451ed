"""The render stage: CPU ray casting (Embree via open3d), lighting, depth sensor models, Zarr + Parquet outputs."""
