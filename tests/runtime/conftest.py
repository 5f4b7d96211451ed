"""Fixtures of the runtime tests."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True, scope="module")
def _tiny_table():
    """The tiny stage's table is registered for these tests only: registered before a module's tests, taken out
    of the registry after them (a unit registers it again whenever it runs in this process, e.g. inline)."""
    from tests.runtime.tiny_stage import register_table

    register_table()
    yield
    from pipeline.store import tables

    tables._REGISTRY.pop("tiny", None)
