"""MVPd pipeline: embodiment-configurable RGB-D video segmentation datasets on Ray.

Stages (each a folder): scenes (shard) -> plan -> render -> evaluate.
The runtime (`pipeline.runtime`) runs them as Ray tasks into a run folder.
"""

__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    # The reading API is imported on first use, so `import pipeline` stays light (no zarr, no numpy).
    if name in ("load_video", "iter_frames", "iter_clips", "list_videos"):
        from pipeline.io import reader

        return getattr(reader, name)
    raise AttributeError(f"module 'pipeline' has no attribute {name!r}")
