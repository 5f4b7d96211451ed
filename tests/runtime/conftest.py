"""Fixtures of the runtime tests."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True, scope="module")
def _forget_tiny_table():
    """The tiny stage's table is registered for these tests only: take it out of the registry afterwards
    (the tiny stage registers it again whenever it runs in this process, e.g. on the inline executor)."""
    yield
    from pipeline.store import tables

    tables._REGISTRY.pop("tiny", None)
