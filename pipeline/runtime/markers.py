"""Markers: a unit's proof of completion and the manifest of its outputs (schemas/README.md, "Commit protocol").

A marker `_state/<stage>/<unit>.json` names every file the unit committed, with its size and CRC-32C,
and is written last. Readers trust only files a marker names (`pipeline.runtime.tables.dataset_parts`),
`mvpd status` checks that each named file exists with its size, and `mvpd status --verify` re-reads
them against their checksums. A unit whose files are missing, resized or (after a verify) corrupt is
*damaged*: it is planned again like a unit without a marker.
"""

from __future__ import annotations

import hashlib
import json
import logging
import mmap
import os
import re
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable

import google_crc32c

from pipeline.lazy_import import lazy_module
from pipeline.runtime.object_store import store_of

# The object-store side of these functions (it builds on this module, so it is imported on first use).
store_markers = lazy_module("pipeline.runtime.store_markers")

log = logging.getLogger(__name__)

STATE = "_state"
MARKER_VERSION = 2
# Which stages committed parts of which dataset: `_state/_datasets/<dataset>/<stage>` (empty files), so a
# reader of one dataset reads the markers of the stages that wrote it, not of every stage of the run.
DATASET_INDEX = "_datasets"
# The driver's status table is committed like a unit of this pseudo-stage (unit = the stage it describes).
STATUS_STAGE = "_status"
DAMAGE_SUFFIX = ".damaged"
_BLOCK = 16 * 2**20

# A name the run looks up (a stage, a unit, a video, a split, an embodiment): no separator and no leading
# dot, so it can never leave the folder it names (`..`, `/abs`, `e/v` are not plain).
_NAME = r"[A-Za-z0-9_\-][A-Za-z0-9_.\-]*"
PLAIN_NAME = re.compile(_NAME)
# A committed file or Zarr store, relative to the run: plain names joined by '/', at least two of them (a
# data folder and a name in it), the first not starting with '_' (`_state/`, `_staging/` and `_attempts/`
# are the run's own). Written for RE2 too: `marker_index` checks a whole manifest column with it.
RUN_PATH = re.compile(rf"[A-Za-z0-9\-][A-Za-z0-9_.\-]*(?:/{_NAME})+")


def is_plain_name(name: str) -> bool:
    """True when `name` may be looked up inside one folder of the run (see PLAIN_NAME)."""
    return isinstance(name, str) and PLAIN_NAME.fullmatch(name) is not None


def is_run_path(path: str) -> bool:
    """True when `path` is a plain relative path of a committed output inside the run (see RUN_PATH):
    never absolute, never `..`, never the run's own bookkeeping."""
    return isinstance(path, str) and RUN_PATH.fullmatch(path) is not None


# Many paths at once, one per line: one regex call for a marker's ~40 paths instead of one each.
_RUN_PATH_LINES = re.compile(rf"(?:{RUN_PATH.pattern}\n)*")


def first_bad_run_path(paths: Iterable[str]) -> str | None:
    """The first of `paths` that is not a run path (`is_run_path`), None when all are."""
    paths = list(paths)
    try:
        lines = "".join(f"{path}\n" for path in paths)
        # As many lines as paths: a path holding a line break is no run path, even if each line would be.
        if lines.count("\n") == len(paths) and _RUN_PATH_LINES.fullmatch(lines) is not None:
            return None
    except TypeError:  # not a string: found below
        pass
    return next(path for path in paths if not is_run_path(path))


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
    with open(path, "rb") as handle:
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


# --------------------------------------------------------------------------------- marker files


def marker_path(root: Path, stage: str, unit: str) -> Path:
    return Path(root) / STATE / stage / f"{unit}.json"


def read_marker(path: Path) -> Marker | None:
    """The marker at `path`, or None when it is missing, unreadable or from before manifests (version 1)."""
    try:
        return parse_marker(path.read_text(encoding="utf-8"), path.name)
    except (FileNotFoundError, UnicodeDecodeError):
        return None


def stage_markers(root: Path, stage: str) -> dict[str, Marker]:
    """Every valid marker of one stage, by unit id (through the stage's marker index, a cache checked
    against one listing of the folder: `pipeline.runtime.marker_index`)."""
    from pipeline.runtime.marker_index import load_markers, marker_folder  # it builds on this module

    return load_markers(marker_folder(root, stage))


def unit_marker(root: Path, stage: str, unit: str) -> Marker | None:
    """One unit's marker, None when it has none (a file read, or one GET on a store)."""
    store = store_of(root)
    if store is not None:
        return store_markers.unit_marker(store, stage, unit)
    return read_marker(marker_path(root, stage, unit))


def write_marker(root: Path, marker: Marker) -> None:
    """Index the marker's datasets, then write the marker atomically (the commit point of the unit)."""
    for dataset in sorted({f.path.split("/")[0] for f in marker.files if f.path.endswith(".parquet")}):
        entry = Path(root) / STATE / DATASET_INDEX / dataset / marker.stage
        if not entry.exists():
            entry.parent.mkdir(parents=True, exist_ok=True)
            entry.touch()
    clear_damage(root, marker.stage, marker.unit)
    atomic_write_text(marker_path(root, marker.stage, marker.unit), marker_text(marker))


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
    except (ValueError, TypeError, KeyError, AttributeError):
        return None  # a damaged marker proves nothing: the unit runs again
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
    prefix = f"_attempts/{marker.stage}/{marker.unit}/"
    for path, key in marker.keys.items():
        if not (isinstance(key, str) and is_run_path(path) and key.startswith(prefix) and key.endswith(f"/{path}")
                and is_plain_name(key[len(prefix):-len(path) - 1])):
            return f"store key {key!r} is not under {prefix}<attempt>/{path}"
    return None


def drop_marker(root: Path, stage: str, unit: str) -> None:
    marker_path(root, stage, unit).unlink(missing_ok=True)
    clear_damage(root, stage, unit)


def stages_writing(root: Path, dataset: str) -> list[str]:
    """Stages with committed parts of `dataset` (from the dataset index, no scan of the data folders)."""
    store = store_of(root)
    if store is not None:
        return store_markers.stages_writing(store, dataset)
    folder = Path(root) / STATE / DATASET_INDEX / dataset
    return sorted(p.name for p in folder.iterdir() if is_plain_name(p.name)) if folder.is_dir() else []


def marked_stages(root: Path) -> list[str]:
    """Stages (including pseudo-stages such as the status table's) that have a marker folder."""
    store = store_of(root)
    if store is not None:
        return store_markers.marked_stages(store)
    folder = Path(root) / STATE
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir() if p.is_dir() and p.name != DATASET_INDEX and is_plain_name(p.name))


# ------------------------------------------------------------------------------------- checking


def check_files(marker: Marker, root: Path, verify: bool = False, recorded: bool = True) -> list[Damage]:
    """Problems of a marker's files: missing or resized (a stat each); with `verify`, also a checksum mismatch.

    `recorded` adds damage an earlier verify or reader noted for this marker (see `record_damage`).
    On object storage, objects are checked only with `verify` (see `store_markers`).
    """
    store = store_of(root)
    if store is not None:
        notes = store_markers.damage_notes(store, marker.stage) if recorded else None
        return store_markers.check_files(store, marker, verify, notes)
    return _check_on_disk(marker, root, verify, recorded)


def _check_on_disk(marker: Marker, root: Path, verify: bool = False, recorded: bool = True) -> list[Damage]:
    # A full-scale render marker names ~40 files and a run 18,000 markers: one os.stat on a joined
    # string per file, no Path object (a Path per file tripled the cost of `mvpd status`).
    prefix = os.path.join(os.fspath(root), "")
    stat = os.stat
    found = []
    # Without `verify` only paths and sizes are needed: a marker from the index gives them as columns.
    entries = (((f.path, f.size, f.crc32c) for f in marker.files) if verify
               else ((path, size, "") for path, size in marker.file_sizes()))
    for path, expected, crc32c in entries:
        try:
            size = stat(prefix + path).st_size
        except (FileNotFoundError, NotADirectoryError):  # NotADirectory: a file where a folder should be
            found.append(Damage(marker.stage, marker.unit, path, "is missing"))
            continue
        if size != expected:
            found.append(Damage(marker.stage, marker.unit, path, f"has {size} bytes, the marker says {expected}"))
        elif verify and file_checksum(Path(prefix + path)) != crc32c:
            found.append(Damage(marker.stage, marker.unit, path, f"fails its checksum (crc32c {crc32c})"))
    if recorded:
        found.extend(recorded_damage(root, marker))
    return found


def unit_damage(root: Path, markers: dict[str, Marker]) -> dict[str, list[Damage]]:
    """Unit id -> problems, for the units of `markers` whose committed files are not as their marker says.

    One thread: over 2 M files on this 2-core machine, two threads of os.stat took 1.3-2.6x as long as
    one (measured on the 18,000 x 120-file run of benchmarks/bench_scaling.py), so the loop stays plain.
    """
    store = store_of(root)
    if store is not None:  # the recorded damage only: one read of each stage's notes (see store_markers)
        notes = {stage: store_markers.damage_notes(store, stage) for stage in {m.stage for m in markers.values()}}
        found = {unit: store_markers.recorded_damage(marker, notes[marker.stage]) for unit, marker in markers.items()}
        return {unit: problems for unit, problems in found.items() if problems}
    damaged = {}
    for unit, marker in markers.items():
        problems = _check_on_disk(marker, root)
        if problems:
            damaged[unit] = problems
    return damaged


def _damage_path(root: Path, stage: str, unit: str) -> Path:
    return Path(root) / STATE / stage / f"{unit}{DAMAGE_SUFFIX}"


# Damage notes this process found but could not write (a read-only run folder), by note path: so that the
# rest of the command (`status --verify` shows the table after verifying) still sees what it found.
_UNWRITTEN_NOTES: dict[str, dict] = {}


def record_damage(root: Path, marker: Marker, problems: list[Damage]) -> None:
    """Remember damage found by reading (a checksum, an unreadable part) so that `rerun` repairs the unit.

    The note names the marker it judged (`finished_at`): a unit committed again since is not affected.
    A read-only run folder keeps no note (this process remembers it); the next verify finds it again.
    """
    store = store_of(root)
    if store is not None:
        store_markers.update_damage(store, marker.stage, [(marker, problems)])
        return
    note = {"finished_at": marker.finished_at, "problems": [asdict(p) for p in problems]}
    path = _damage_path(root, marker.stage, marker.unit)
    try:
        atomic_write_text(path, json.dumps(note, indent=1))
    except OSError as error:
        _UNWRITTEN_NOTES[str(path)] = note
        log.warning("cannot record damage of %s/%s: %s", marker.stage, marker.unit, error)


def recorded_damage(root: Path, marker: Marker) -> list[Damage]:
    """Damage recorded by an earlier verify or read for this very marker."""
    store = store_of(root)
    if store is not None:
        return store_markers.recorded_damage(marker, store_markers.damage_notes(store, marker.stage))
    path = _damage_path(root, marker.stage, marker.unit)
    note = _UNWRITTEN_NOTES.get(str(path))
    try:
        if note is None:
            note = json.loads(path.read_text(encoding="utf-8"))
        if note["finished_at"] != marker.finished_at:
            return []
        return [Damage(**p) for p in note["problems"]]
    except FileNotFoundError:
        return []
    except (ValueError, TypeError, KeyError):
        return [Damage(marker.stage, marker.unit, f"{STATE}/{marker.stage}/{marker.unit}{DAMAGE_SUFFIX}",
                       "is an unreadable damage note")]


def clear_damage(root: Path, stage: str, unit: str) -> None:
    store = store_of(root)
    if store is not None:
        store_markers.update_damage(store, stage, cleared=[unit])
        return
    path = _damage_path(root, stage, unit)
    _UNWRITTEN_NOTES.pop(str(path), None)
    if path.exists():  # never unlink a note that is not there: on a read-only file system that fails (EROFS)
        path.unlink(missing_ok=True)


def atomic_write_text(path: Path, text: str) -> None:
    """Write a small text file by temp file + rename, so readers see the old or the new file whole."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    temporary.write_text(text, encoding="utf-8")
    os.replace(temporary, path)
