"""A tiny rendered run shared by the model tests (two embodiments, two heights, 17 frames per video)."""

from __future__ import annotations

from pathlib import Path

import pytest

import tests.render.tiny_run as tiny_run

FRAMES = 17  # one published window (windows start while start < T - 15)


@pytest.fixture(scope="session")
def run_root(tmp_path_factory) -> Path:
    """The tiny two-embodiment run of tests/render, 17 frames per video, rendered once."""
    root = tmp_path_factory.mktemp("models") / "run"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tiny_run, "FRAMES", FRAMES)
        tiny_run.render_tiny_run(root)
    return root
