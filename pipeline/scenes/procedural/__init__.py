"""Procedural houses: layout (rooms, doors, windows, walls), furniture templates, placement, colours."""


def procedural_scene_id(seed: int) -> str:
    """Id of the generated house of a seed: `proc-<seed:06d>` (here, below `sources`, which lists them)."""
    return f"proc-{seed:06d}"
