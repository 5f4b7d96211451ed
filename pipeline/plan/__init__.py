"""The plan stage: navigable area of a scene for a robot body, floor paths, camera trajectories.

navigable.py     the navigable area: a layered floor grid from ray casts, eroded by the body radius
search.py        shortest grid paths (on a 2x coarser graph, expanded back to the grid)
paths.py         start/goal draws, string pulling, pose clearance checks on the mesh
interpolation.py floor path -> frames (straight moves, in-place turns) -> camera poses per placement
poses.py         quaternion / matrix helpers and OpenCV camera-to-world poses (imported by render)
stage.py         `PathPlanner`: one unit per (scene, embodiment)
preview.py       top-down picture of the navigable area and the paths (`mvpd plan preview`)
report.py        per-unit status and draw counts from the markers (`mvpd plan report`)
synthetic.py     box-built scenes (rooms, thin walls, doorways, stairs) for tests and benchmarks

Run-folder files: `trajectories/` and `frames/` (tables.py) and `navmesh/<scene_id>.<key>.npz`, the
cached navigable area of a scene for one body (key: hash of the scene row, body, grid resolution and
format), read back by every unit with the same scene and body.
"""
