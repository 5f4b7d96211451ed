"""MVPd pipeline: embodiment-configurable RGB-D video segmentation datasets on Ray.

Stages (each a folder): scenes (shard) -> plan -> render -> evaluate.
The runtime (`pipeline.runtime`) runs them as Ray tasks into a run folder.
"""

__version__ = "0.1.0"
