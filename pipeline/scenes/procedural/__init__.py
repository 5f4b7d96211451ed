"""Procedural houses: layout (rooms, doors, windows, walls), furniture templates, placement, colours."""
