"""Shared tiny scenes: one small generated house and its HM3DSem files, built once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.scenes.hm3dsem import write_hm3dsem
from pipeline.scenes.procedural.house import generate_house
from pipeline.scenes.scene import Scene


@pytest.fixture(scope="session")
def small_house() -> Scene:
    """A 3-4 room house at the lowest detail (about 50 k triangles)."""
    return generate_house(seed=7, detail=0.05, min_rooms=3, max_rooms=4)


@pytest.fixture(scope="session")
def house_files(small_house: Scene, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small house written as HM3DSem files; returns its `.semantic.txt`."""
    return write_hm3dsem(small_house, tmp_path_factory.mktemp("hm3dsem"))
