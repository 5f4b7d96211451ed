"""Scenes: the `Scene` every stage uses, where scenes come from, and the `shard` stage.

    scene.py        Scene / SceneObject / SceneRef / SceneError (the shared API)
    categories.py   mpcat40 categories and the raw-name mapping
    sources.py      list the job's scenes; load a ref, a file or a `scenes` row (`load_scene_row`)
    procedural/     generated houses: layout, stairs, furniture, placement, colours, tessellation
    glb.py          strict GLB reader / deterministic writer
    hm3dsem.py      HM3DSem trio reader and writer (+Z up files, exact round trip)
    meshes.py       plain OBJ / PLY / GLB meshes with instance labels and a JSON of names
    preview.py      top-down picture and statistics
    shard.py        the `shard` stage -> `scenes` and `objects` tables (tables.py)
"""
