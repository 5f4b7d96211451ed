"""Markers: a unit's proof of completion and the manifest of its outputs (schemas/README.md, "Commit protocol").

A marker `_state/<stage>/<unit>.json` names every file the unit committed, with its size and CRC-32C,
and is written last. Readers trust only files a marker names (`pipeline.store.datasets`), `mvpd status`
checks that each named file exists with its size, and `mvpd status --verify` re-reads them against their
checksums. A unit whose files are missing, resized or (after a verify) corrupt is *damaged*: it is planned
again like a unit without a marker. This module is the markers' content; where they live is the run
folder's (`pipeline.store.run_folder`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import mmap
import os
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable

import google_crc32c

from pipeline.store.names import ATTEMPTS, first_bad_run_path, is_plain_name, is_run_path

log = logging.getLogger(__name__)

MARKER_VERSION = 2
_BLOCK = 16 * 2**20


@dataclass(frozen=True)
class OutputFile:
    """One committed file: path relative to the run folder ('/'-separated), size in bytes, CRC-32C (hex)."""

    path: str
    size: int
    crc32c: str


@dataclass
class Marker:
    """Proof that a unit committed, written last and atomically; `files` is the manifest readers trust."""

    stage: str
    unit: str
    config_hash: str
    code_version: str
    outputs: list[str]
    rows: dict[str, int]
    seconds: float
    attempt: int
    host: str
    finished_at: float
    info: dict[str, Any] = field(default_factory=dict)
    files: list[OutputFile] = field(default_factory=list)
    version: int = MARKER_VERSION
    node: str = ""  # the Ray node id of the worker that committed ("" inline): `host` is one name per machine
    # On object storage: logical path of each file -> its key, unique to the unit and attempt (relative
    # to the run's prefix). Empty on local disk, where files are renamed to their logical paths.
    keys: dict[str, str] = field(default_factory=dict)

    def __getattr__(self, name: str) -> Any:
        """`files` of a marker loaded from the stage's index, made on first use (`ColumnarManifest`)."""
        manifest = self.__dict__.get("_manifest")
        if name != "files" or manifest is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        files = manifest.output_files()
        self.__dict__["files"] = files
        del self.__dict__["_manifest"]
        return files

    def __getstate__(self) -> dict[str, Any]:
        self.files  # noqa: B018 - a pickled or copied marker carries its list, not the index's columns
        return self.__dict__

    def file_sizes(self) -> Iterable[tuple[str, int]]:
        """(path, size) of every committed file, without making an `OutputFile` each when still columnar."""
        manifest = self.__dict__.get("_manifest")
        if manifest is not None:
            return zip(manifest.paths.to_pylist(), manifest.sizes.to_pylist())
        return ((entry.path, entry.size) for entry in self.files)


@dataclass(frozen=True)
class ColumnarManifest:
    """A marker's manifest as the index's Arrow columns (slices): a stage of 18,000 markers names 2 M files,
    and `mvpd status` needs only their paths and sizes, so the `OutputFile`s are made only when asked for."""

    paths: Any  # pyarrow.StringArray
    sizes: Any  # pyarrow.Int64Array
    crcs: Any  # pyarrow.StringArray

    def output_files(self) -> list[OutputFile]:
        return list(map(OutputFile, self.paths.to_pylist(), self.sizes.to_pylist(), self.crcs.to_pylist()))


@dataclass(frozen=True)
class Damage:
    """A problem with one committed file of one unit (`path` relative to the run folder)."""

    stage: str
    unit: str
    path: str
    problem: str

    def line(self) -> str:
        return f"{self.stage}/{self.unit}: {self.path} {self.problem}"


# ------------------------------------------------------------------------------------ checksums


def file_checksum(path: Path) -> str:
    """CRC-32C of a file as 8 hex digits (hardware-accelerated; the checksum S3 and GCS also keep).

    Big files are mapped and summed in blocks (twice as fast as buffered reads from the page cache).
    """
    # O_NOFOLLOW: a committed file that became a link is never read through (pipeline.store.links).
    with open(path, "rb", opener=lambda name, flags: os.open(name, flags | os.O_NOFOLLOW)) as handle:
        size = os.fstat(handle.fileno()).st_size
        if size < _BLOCK:
            return f"{google_crc32c.value(handle.read()):08x}"
        crc = 0
        with mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
            for start in range(0, size, _BLOCK):
                crc = google_crc32c.extend(crc, mapped[start:start + _BLOCK])
    return f"{crc:08x}"


def describe_files(root: Path, relative_paths: Iterable[str]) -> list[OutputFile]:
    """Manifest entries of committed outputs below `root`; a folder (a Zarr store) is listed file by file."""
    files = []
    for relative in relative_paths:
        path = root / relative
        members = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
        for member in members:
            files.append(OutputFile(member.relative_to(root).as_posix(), member.stat().st_size, file_checksum(member)))
    return sorted(files, key=lambda f: f.path)


@lru_cache(maxsize=1)
def code_version() -> str:
    """Package version + hash of the package's source files: changes whenever the code does."""
    from pipeline import __version__

    digest = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parents[1].rglob("*.py")):
        digest.update(path.read_bytes())
    return f"{__version__}+{digest.hexdigest()[:12]}"


# ------------------------------------------------------------------------------ marker text


def marker_text(marker: Marker) -> str:
    """The marker as JSON (`keys` only on object storage, so local markers are as before)."""
    data = asdict(marker)
    if not data["keys"]:
        del data["keys"]
    return json.dumps(data, indent=1, sort_keys=True)


def parse_marker(text: str, name: str | None = None) -> Marker | None:
    """A marker from its JSON text; None when unreadable, from before manifests (version 1), or naming a
    path that is not a plain one inside the run (`marker_problem`); `name` is its file name, `<unit>.json`."""
    try:
        data = json.loads(text)
        if data.get("version", 1) < MARKER_VERSION:
            return None  # no manifest: nothing can be checked, so it proves nothing; the unit runs again
        data["files"] = [OutputFile(**f) for f in data["files"]]
        marker = Marker(**data)
    except (ValueError, TypeError, KeyError, AttributeError, RecursionError):
        return None  # a damaged marker (`[` nested 200,000 deep too) proves nothing: the unit runs again
    problem = marker_problem(marker, name, [f.path for f in marker.files])
    if problem is not None:
        log.warning("marker %s/%s ignored: %s; the unit runs again", marker.stage, marker.unit, problem)
        return None
    return marker


def marker_problem(marker: Marker, name: str | None, file_paths: Iterable[str] | None) -> str | None:
    """Why a marker must not be followed (None when it may), checked before any path it names is used.

    A tampered marker naming `../../x`, `/abs` or `job.yaml` would otherwise make a commit delete or a
    reader read outside the unit's outputs. Stage and unit must be plain names (they make the marker's
    own paths) matching its file `name`; every output and file a plain relative path in the run; on a
    store, every key under the unit's `_attempts/<stage>/<unit>/<attempt>/` and ending in its logical path.
    `file_paths` None: checked by the caller (the marker index checks its manifest column in one go).
    """
    if not (is_plain_name(marker.stage) and is_plain_name(marker.unit)):
        return f"stage {marker.stage!r} or unit {marker.unit!r} is not a plain name"
    if name is not None and name != f"{marker.unit}.json":
        return f"its file {name!r} is not named after its unit {marker.unit!r}"
    if not isinstance(marker.outputs, list) or not isinstance(marker.keys, dict):
        return "outputs or keys are of the wrong type"
    bad = first_bad_run_path([*marker.outputs, *(file_paths or ())])
    if bad is not None:
        return f"path {bad!r} is not a plain relative path inside the run"
    prefix = f"{ATTEMPTS}/{marker.stage}/{marker.unit}/"
    for path, key in marker.keys.items():
        if not (isinstance(key, str) and is_run_path(path) and key.startswith(prefix) and key.endswith(f"/{path}")
                and is_plain_name(key[len(prefix):-len(path) - 1])):
            return f"store key {key!r} is not under {prefix}<attempt>/{path}"
    return None
