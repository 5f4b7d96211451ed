"""Modules loaded on first use, so that commands which never touch them (`mvpd status`) start fast."""

from __future__ import annotations

import importlib.util
import re
import sys
from importlib.abc import Loader
from importlib.machinery import ModuleSpec
from types import ModuleType

from pipeline.errors import error_text

# The apt package of each system library our native modules load (deploy/setup.sh's SYSTEM_PACKAGES), by
# the library's name up to `.so`: open3d loads libusb at import, and needs OpenMP and libGL.
APT_PACKAGES = {"libusb-1.0.so": "libusb-1.0-0", "libgomp.so": "libgomp1", "libGL.so": "libgl1",
                "libOSMesa.so": "libosmesa6"}
_MISSING_LIBRARY = re.compile(r"(([\w.+-]+?\.so)[\w.]*): cannot open shared object file")  # the loader's words


class ModuleLoadError(ImportError):
    """A lazily loaded module failed to import; the message is one line saying what is missing and what to do."""


def lazy_module(name: str) -> ModuleType:
    """`name` as a module whose code runs on its first attribute access (importlib's LazyLoader recipe).

    For heavy libraries used only inside functions (open3d's import alone takes about a second). If the
    module's code fails (say a system library is missing), that access and every later one raise the same
    ModuleLoadError: the half-run module stays in sys.modules, where it would otherwise answer the next
    unit with "module 'open3d' has no attribute 't'".
    """
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None or spec.loader is None:
        raise ModuleNotFoundError(f"No module named {name!r}", name=name)
    loader = importlib.util.LazyLoader(_RememberingLoader(spec.loader))
    spec.loader = loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    loader.exec_module(module)
    return module


def load_failure_line(name: str, error: BaseException) -> str:
    """One line for module `name` failing to import with `error`: the missing library's apt package, or the error."""
    text = error_text(error, None)
    missing = _MISSING_LIBRARY.search(text)
    if missing is None:
        return f"{name} cannot be imported ({type(error).__name__}: {text}); run `make setup` to reinstall it"
    library, stem = missing.groups()
    package = APT_PACKAGES.get(stem)
    install = (f"install the apt package {package} (sudo apt-get install {package})" if package
               else f"install the system package that provides {library}")
    return f"{name} cannot load the system library {library}: {install}, or run `make setup`"


class _RememberingLoader(Loader):
    """Runs the real loader's module code; on failure turns the module into one that repeats the failure."""

    def __init__(self, loader: Loader) -> None:
        self.loader = loader

    def create_module(self, spec: ModuleSpec) -> ModuleType | None:
        return self.loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        module.__spec__.loader = module.__loader__ = self.loader  # the loaded module sees its own loader
        try:
            self.loader.exec_module(module)
        except Exception as error:
            line = load_failure_line(module.__spec__.name, error)
            module.__load_failure__ = line  # type: ignore[attr-defined]
            module.__class__ = _FailedModule
            raise ModuleLoadError(line, name=module.__spec__.name) from error


class _FailedModule(ModuleType):
    """A module whose code failed: every attribute access raises its ModuleLoadError again.

    Dunder names still answer, so repr, pickling by name and the import system can handle the module.
    """

    def __getattribute__(self, attribute: str) -> object:
        if attribute.startswith("__") and attribute.endswith("__"):
            return super().__getattribute__(attribute)
        name = super().__getattribute__("__name__")
        raise ModuleLoadError(super().__getattribute__("__load_failure__"), name=name)
