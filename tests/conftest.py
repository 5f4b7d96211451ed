"""Shared fixtures: one local Ray for the whole session, and tiny jobs."""

from __future__ import annotations

import os
import sys

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


# What the dynamic loader says when a native module's system library is absent (open3d without libusb).
MISSING_LIBUSB = "libusb-1.0.so.0: cannot open shared object file: No such file or directory"


@pytest.fixture
def unloadable_module(tmp_path, monkeypatch):
    """The name of a module on sys.path whose import fails half-way, as open3d's does without libusb."""
    name = "unloadable_native_module"
    (tmp_path / f"{name}.py").write_text(f"VERSION = '1.0'  # set before the failure: the module is half-run\n"
                                         f"raise ImportError({MISSING_LIBUSB!r})\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield name
    sys.modules.pop(name, None)
