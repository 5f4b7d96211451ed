"""Lazily loaded modules: loaded on first use, and a module whose import fails says so the same way every time."""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest

from pipeline.lazy_import import APT_PACKAGES, ModuleLoadError, lazy_module, load_failure_line
from tests.conftest import MISSING_LIBUSB

FIX = "unloadable_native_module cannot load the system library libusb-1.0.so.0: install the apt package libusb-1.0-0"


def test_a_module_runs_on_first_use_and_keeps_its_own_loader(tmp_path, monkeypatch) -> None:
    ran = tmp_path / "ran"
    (tmp_path / "counted_module.py").write_text(f"open({str(ran)!r}, 'a').write('ran\\n')\nVALUE = 7\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        module = lazy_module("counted_module")
        assert not ran.exists()
        assert module.VALUE == 7 and module.VALUE == 7 and ran.read_text() == "ran\n"
        assert type(module.__loader__).__name__ == "SourceFileLoader" and importlib.import_module("counted_module") is module
    finally:
        sys.modules.pop("counted_module", None)


def test_a_missing_system_library_is_the_same_clear_error_on_every_use(unloadable_module: str) -> None:
    module = lazy_module(unloadable_module)
    failures = []
    for _ in range(3):  # before, the second use said "module ... has no attribute 'geometry'"
        with pytest.raises(ModuleLoadError) as raised:
            module.geometry
        failures.append(str(raised.value))
    with pytest.raises(ModuleLoadError) as imported:  # an ordinary import later finds the same failed module
        importlib.import_module(unloadable_module).geometry
    assert failures == [f"{FIX} (sudo apt-get install libusb-1.0-0), or run `make setup`"] * 3 == [str(imported.value)] * 3
    assert isinstance(raised.value, ImportError) and not isinstance(raised.value, OSError)  # a unit failure, not the disk's
    assert "unloadable_native_module" in repr(module)


@pytest.mark.parametrize(("error", "line"), [
    (OSError(f"/opt/lib/{MISSING_LIBUSB}"), f"{FIX} (sudo apt-get install libusb-1.0-0), or run `make setup`"),
    (ImportError("libfoo.so.3: cannot open shared object file: No such file or directory"),
     "m cannot load the system library libfoo.so.3: install the system package that provides libfoo.so.3, or run `make setup`"),
    (ModuleNotFoundError("No module named 'numcodecs'"),
     "m cannot be imported (ModuleNotFoundError: No module named 'numcodecs'); run `make setup` to reinstall it"),
])
def test_the_failure_line_names_the_library_and_its_apt_package(error: Exception, line: str) -> None:
    name = "unloadable_native_module" if "libusb" in line else "m"
    assert load_failure_line(name, error) == line


def test_every_apt_package_named_is_one_setup_installs() -> None:
    setup = (Path(__file__).resolve().parents[1] / "deploy" / "setup.sh").read_text()
    installed = {name for group in re.findall(r"SYSTEM_PACKAGES\+?=\(([^)]*)\)", setup) for name in group.split()}
    assert set(APT_PACKAGES.values()) <= installed
