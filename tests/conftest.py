"""Shared fixtures: one local Ray for the whole session, and tiny jobs."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")


@pytest.fixture(scope="session")
def ray_session():
    """A quiet local Ray with 2 CPUs, started once and shut down at the end."""
    import ray

    from pipeline.runtime.ray_session import ensure_ray

    ensure_ray(num_cpus=2)
    yield ray
    ray.shutdown()
