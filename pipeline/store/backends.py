"""Where a run's bytes are: a folder on local disk (`LocalFiles`) or a prefix of an object store
(`StoreFiles`). `RunFolder` chooses one when it is opened and speaks to it alone; nothing else asks
which of the two a run is.

What differs on object storage (schemas/README.md, "On object storage"):

- Objects are written whole by one PUT each, under keys unique to the unit's attempt, before their marker,
  and never renamed or changed. The marker maps each logical path to its key (`Marker.keys`).
- Markers come from the stage's marker index and one listing of `_state/<stage>/`.
- `status` does not ask the store about each of a unit's ~40 objects (0.7 M requests at MVPd scale): it
  reports the damage a verify or a reader recorded; `status --verify` lists each unit's attempt prefix
  (sizes) and reads every object (CRC-32C).
- Damage notes of a stage are one object, `_state/<stage>/_damage.notes` ({unit: note}), so `status`
  reads one object per stage, not one per unit. Two writers at once may lose a note; the next verify
  finds the damage again (a note only speeds repair up). On local disk a note is a file per unit,
  `_state/<stage>/<unit>.damaged`.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from dataclasses import asdict
from pathlib import Path
from stat import S_ISLNK, S_ISREG
from typing import Any, Callable, Iterable

import google_crc32c
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.errors import error_text
from pipeline.store.lock import LOCK_KEY, RemoteRunLock, RunLock, local_holder, parse_holder
from pipeline.store.marker_index import MAX_MARKER_BYTES, FsspecMarkerFolder, LocalMarkerFolder, MarkerFolder
from pipeline.store.markers import Damage, Marker, OutputFile, file_checksum, marker_text, parse_marker
import pipeline.store.links as links
from pipeline.store.links import FolderCheck
from pipeline.store.names import (ATTEMPTS, DATASET_INDEX, JOB_FILE, STATE, RunFolderError, atomic_write_text,
                                  is_plain_name, is_run_path)
from pipeline.store.remote import RunStore, StoreError, attempt_id

log = logging.getLogger(__name__)

DAMAGE_SUFFIX = ".damaged"
DAMAGE_NOTES = "_damage.notes"
# Damage notes this process found but could not write (a read-only run folder), by note path: so that the
# rest of the command (`status --verify` shows the table after verifying) still sees what it found.
_UNWRITTEN_NOTES: dict[str, dict] = {}


def _note(marker: Marker, problems: list[Damage]) -> dict:
    return {"finished_at": marker.finished_at, "problems": [asdict(p) for p in problems]}


def _noted_damage(marker: Marker, note: Any, where: str) -> list[Damage]:
    """The damage `note` records for this very marker (a unit committed again since has none)."""
    try:
        if not note or note["finished_at"] != marker.finished_at:
            return []
        return [Damage(**p) for p in note["problems"]]
    except (TypeError, KeyError):
        return _unreadable_note(marker, where)


def _unreadable_note(marker: Marker, where: str) -> list[Damage]:
    return [Damage(marker.stage, marker.unit, where, "is an unreadable damage note")]


class LocalFiles:
    """A run folder on local disk or a shared file system: outputs are renamed into place."""

    def __init__(self, root: Path):
        self.root = root
        self.location = str(root)

    # ------------------------------------------------------------------------------- the folder
    def prepare(self) -> None:
        """Create the folder (or find a run in it); refuses a file or a non-empty folder that is not a run."""
        root = self.root
        if root.exists() and not root.is_dir():
            raise RunFolderError(f"{root}: is a file, not a run folder; choose a folder path")
        if root.exists() and any(root.iterdir()) and not self.is_run():
            raise RunFolderError(f"{root}: exists, is not empty and has no {JOB_FILE}; choose an empty or new folder")
        try:
            root.mkdir(parents=True, exist_ok=True)
        except OSError as error:  # read-only file system, a parent that is a file, no permission
            raise RunFolderError(f"{root}: cannot create the run folder ({error.strerror}); "
                                 "choose a writable place (--run-dir)") from None

    def is_run(self) -> bool:
        """A run folder, or one `prepare` began (its `_state` folder is made first)."""
        return os.path.lexists(self.root / STATE)

    def check_run(self) -> None:
        if not _is_file(self.root / JOB_FILE):
            raise RunFolderError(f"{self.root}: not a run folder (no {JOB_FILE}); give the folder `mvpd submit` wrote")

    def save_job(self, text: str) -> None:
        links.make_folder(self.root, STATE)  # what makes a folder a run (`is_run_folder`), before its job file
        links.write_file(self.root, JOB_FILE, text.encode("utf-8"))

    def read_job(self) -> str:
        return links.read_bytes(self.root, JOB_FILE).decode("utf-8")

    # ---------------------------------------------------------------------------------- markers
    def marker_folder(self, stage: str) -> MarkerFolder:
        return LocalMarkerFolder(self.root, stage)

    def read_marker(self, stage: str, unit: str) -> Marker | None:
        try:
            data = links.read_bytes(self.root, f"{STATE}/{stage}/{unit}.json", MAX_MARKER_BYTES + 1)
            text = data.decode("utf-8")
        except (OSError, UnicodeDecodeError, RunFolderError):  # missing, a folder, a link: no proof of anything
            return None
        return parse_marker(text, f"{unit}.json") if len(data) <= MAX_MARKER_BYTES else None

    def write_marker(self, marker: Marker) -> None:
        """Index the marker's datasets, then write the marker atomically (the commit point of the unit)."""
        for dataset in sorted({f.path.split("/")[0] for f in marker.files if f.path.endswith(".parquet")}):
            entry = f"{STATE}/{DATASET_INDEX}/{dataset}/{marker.stage}"
            if not os.path.lexists(self.root / entry):
                links.write_file(self.root, entry, b"")
        self._clear_note(marker.stage, marker.unit)
        links.write_file(self.root, f"{STATE}/{marker.stage}/{marker.unit}.json", marker_text(marker).encode("utf-8"))

    def drop_marker(self, stage: str, unit: str) -> None:
        links.remove(self.root, f"{STATE}/{stage}/{unit}.json")
        self._clear_note(stage, unit)

    def stages_writing(self, dataset: str) -> list[str]:
        return sorted(name for name, _ in links.entries(self.root, f"{STATE}/{DATASET_INDEX}/{dataset}")
                      if is_plain_name(name))

    def marked_stages(self) -> list[str]:
        return sorted(name for name, is_folder in links.entries(self.root, STATE)
                      if is_folder and name != DATASET_INDEX and is_plain_name(name))

    def datasets(self) -> list[str]:
        return sorted(name for name, is_folder in links.entries(self.root, f"{STATE}/{DATASET_INDEX}")
                      if is_folder and links.entries(self.root, f"{STATE}/{DATASET_INDEX}/{name}"))

    # ----------------------------------------------------------------------------------- damage
    def check(self, marker: Marker, verify: bool, folders: FolderCheck | None = None,
              deep: bool = True) -> list[Damage]:
        """Missing, resized or linked files (an lstat each) and outputs reached through a link (an lstat per
        folder and pass `folders`); with `verify`, also a checksum mismatch. `deep` also checks every folder
        inside a Zarr store (a reader about to open it; `status` checks the store's own folder: a full-scale
        store nests ~80 folders for its ~40 files). Nothing is followed through a link (`pipeline.store.links`)."""
        # A full-scale render marker names ~40 files and a run 18,000 markers: one os.lstat on a joined
        # string per file, no Path object (a Path per file tripled the cost of `mvpd status`).
        folders = folders or FolderCheck(self.root)
        prefix, lstat, folder_problem, real = folders.prefix, os.lstat, folders.problem, folders.real
        # Without `verify` only paths and sizes are needed: a marker from the index gives them as columns.
        entries = ([(f.path, f.size, f.crc32c) for f in marker.files] if verify
                   else [(path, size, "") for path, size in marker.file_sizes()])
        blocked = _blocked_outputs(marker.outputs, {entry[0] for entry in entries}, folder_problem)
        found = []
        for path, expected, crc32c in entries:
            problem = next((p for o, p in blocked.items() if path.startswith(o)), None) if blocked else None
            if deep and problem is None:
                parent = path.rpartition("/")[0]
                problem = None if parent in real else folder_problem(parent)
            if problem is None:
                try:
                    info = lstat(prefix + path)
                    size = info.st_size
                    problem = "is a symbolic link" if S_ISLNK(info.st_mode) else None
                except OSError:  # missing, or a loop or a file where a folder should be
                    problem = "is missing"
            if problem is not None:
                found.append(Damage(marker.stage, marker.unit, path, problem))
                continue
            if size != expected:
                found.append(Damage(marker.stage, marker.unit, path, f"has {size} bytes, the marker says {expected}"))
            elif verify and file_checksum(Path(prefix + path)) != crc32c:
                found.append(Damage(marker.stage, marker.unit, path, f"fails its checksum (crc32c {crc32c})"))
        return found

    def recorded_damage(self, markers: list[Marker]) -> list[list[Damage]]:
        """The damage noted for each marker by an earlier verify or reader (one note file per unit)."""
        return [self._recorded(marker) for marker in markers]

    def _recorded(self, marker: Marker) -> list[Damage]:
        where = self._note_path(marker.stage, marker.unit)
        note = _UNWRITTEN_NOTES.get(str(self.root / where))
        try:
            if note is None:
                os.lstat(self.root / where)  # most units have no note: one syscall, as reading one was
                note = json.loads(links.read_bytes(self.root, where))
        except FileNotFoundError:
            return []
        except (ValueError, RecursionError, OSError, RunFolderError):  # bad JSON, a folder, a link
            return _unreadable_note(marker, where)
        return _noted_damage(marker, note, where)

    def update_damage(self, stage: str, damaged: Iterable[tuple[Marker, list[Damage]]] = (),
                      cleared: Iterable[str] = ()) -> None:
        """Note damage of some units of a stage, forget that of others. A read-only run folder keeps no
        note (this process remembers it; the next verify finds it again) and its old notes stay."""
        for marker, problems in damaged:
            path = self._note_path(stage, marker.unit)
            try:
                links.write_file(self.root, path, json.dumps(_note(marker, problems), indent=1).encode("utf-8"))
            except (OSError, RunFolderError) as error:
                _UNWRITTEN_NOTES[str(self.root / path)] = _note(marker, problems)
                log.warning("cannot record damage of %s/%s: %s", stage, marker.unit, error)
        for unit in cleared:
            try:
                self._clear_note(stage, unit)
            except (OSError, RunFolderError) as error:
                log.warning("cannot clear the damage note of %s/%s: %s", stage, unit, error)

    @staticmethod
    def _note_path(stage: str, unit: str) -> str:
        return f"{STATE}/{stage}/{unit}{DAMAGE_SUFFIX}"

    def _clear_note(self, stage: str, unit: str) -> None:
        path = self._note_path(stage, unit)
        _UNWRITTEN_NOTES.pop(str(self.root / path), None)
        # Never unlink a note that is not there: on a read-only file system that fails (EROFS).
        if os.path.lexists(self.root / path):
            links.remove(self.root, path)

    # -------------------------------------------------------------------------- committed files
    def path_of(self, marker: Marker, relative: str) -> Path:
        """Where a file or Zarr store committed by `marker` is read: its path in the run."""
        return self.root / relative

    def read_part(self, location: Path | str, schema: pa.Schema, **options: Any) -> pa.Table:
        return pq.read_table(location, schema=schema, **options)

    def commit(self, stage: str, unit: str, staging: Path, files: list[OutputFile], outputs: list[str],
               previous: Marker | None) -> dict[str, str]:
        """Move the staged `outputs` (files or Zarr stores) into place, replacing earlier versions; no keys.

        Outputs of the unit's previous commit that this attempt did not produce are removed, so a
        rerun never leaves stale rows or videos behind.
        """
        staged = staging.relative_to(self.root).as_posix()
        for relative in outputs:
            links.replace(self.root, f"{staged}/{relative}", self.inside(relative))
        self._remove(sorted(set(previous.outputs if previous else []) - set(outputs)))
        links.remove(self.root, staged)
        return {}

    def forget(self, previous: Marker, keys: dict[str, str]) -> None:
        """Nothing to do on disk: a commit replaced or removed the previous attempt's files."""

    def retire(self, marker: Marker) -> None:
        """Remove the outputs of a unit the job no longer has (its marker is already gone)."""
        self._remove(marker.outputs)

    def _remove(self, relatives: Iterable[str]) -> None:
        for relative in relatives:
            links.remove(self.root, self.inside(relative))

    def inside(self, relative: str) -> str:
        """`relative`, after checking that it is a plain relative path of an output inside the run
        (`is_run_path`). Markers are checked when read; this is the last guard of the name before anything is
        moved or deleted (RunFolderError otherwise); `links` then follows no link on the way."""
        if not is_run_path(relative):
            raise RunFolderError(f"{self.root}: refusing to write or delete {relative!r}, which is not a plain "
                                 "relative path inside the run")
        return relative

    def upload_log(self, stage: str, unit: str, local: Path) -> None:
        """Logs are written in place."""

    # ------------------------------------------------------------------------------------- lock
    def lock(self) -> RunLock:
        return RunLock(self.root)

    def lock_holder(self) -> dict | None:
        return local_holder(self.root / LOCK_KEY)


class StoreFiles:
    """A run on an object store, read where it is: no local copy of it is made (see the module doc)."""

    def __init__(self, store: RunStore, root: Path):
        self.store = store
        self.root = root  # the local folder standing for the run: job file, staging, logs before upload
        self.location = store.url
        self._indexed: set[str] = set()  # dataset index entries known to be on the store

    # ------------------------------------------------------------------------------- the folder
    def prepare(self) -> None:
        """Check the store; refuses a non-empty prefix that is not a run."""
        self._check_store()
        # A run's first key is its lock (`_state/`): a driver starting beside another finds the lock, not
        # a foreign folder, and is told who holds it.
        if not self.store.exists(JOB_FILE) and not self.store.exists(STATE) and self.store.exists(""):
            raise RunFolderError(f"{self.location}: exists, is not empty and has no {JOB_FILE}; "
                                 "choose an empty or new prefix")
        self._fetch_job()

    def check_run(self) -> None:
        self._check_store()
        if not self.store.exists(JOB_FILE):
            raise RunFolderError(f"{self.location}: not a run folder (no {JOB_FILE}); give the URL `mvpd submit` wrote")
        self._fetch_job()

    def _check_store(self) -> None:
        try:
            self.store.check()
        except StoreError as error:
            raise RunFolderError(str(error)) from None

    def _fetch_job(self) -> None:
        """Keep the job file of a remote run in its local folder (one GET; the only file copied)."""
        job = self.store.read_text(JOB_FILE)
        if job is not None and job != _read(self.root / JOB_FILE):
            atomic_write_text(self.root / JOB_FILE, job)

    def save_job(self, text: str) -> None:
        atomic_write_text(self.root / JOB_FILE, text)
        self.store.put_text(JOB_FILE, text)

    # ---------------------------------------------------------------------------------- markers
    def marker_folder(self, stage: str) -> MarkerFolder:
        return FsspecMarkerFolder(self.store.fs, self.store.key(f"{STATE}/{stage}"))

    def read_marker(self, stage: str, unit: str) -> Marker | None:
        """One unit's marker (one GET); None when it has none."""
        text = self.store.read_text(self._marker_key(stage, unit))
        return parse_marker(text, f"{unit}.json") if text is not None else None

    def write_marker(self, marker: Marker) -> None:
        """Index the marker's datasets, then PUT the marker, last of all the unit's objects (the commit point)."""
        for dataset in sorted({f.split("/")[0] for f in marker.outputs if f.endswith(".parquet")}):
            entry = f"{STATE}/{DATASET_INDEX}/{dataset}/{marker.stage}"
            if entry not in self._indexed:  # one HEAD per dataset per run folder, a PUT only the first time
                if not self.store.exists(entry):
                    self.store.put_text(entry, "")
                self._indexed.add(entry)
        self.store.put_text(self._marker_key(marker.stage, marker.unit), marker_text(marker))

    def drop_marker(self, stage: str, unit: str) -> None:
        self.store.remove([self._marker_key(stage, unit)])

    @staticmethod
    def _marker_key(stage: str, unit: str) -> str:
        return f"{STATE}/{stage}/{unit}.json"

    def stages_writing(self, dataset: str) -> list[str]:
        """Stages with committed parts of `dataset`: one listing of `_state/_datasets/<dataset>/`."""
        return self._names(f"{STATE}/{DATASET_INDEX}/{dataset}", "file")

    def marked_stages(self) -> list[str]:
        """Stages with a marker folder on the store: one listing of `_state/`."""
        return [name for name in self._names(STATE, "directory") if name != DATASET_INDEX]

    def datasets(self) -> list[str]:
        """Datasets some stage has committed parts of: one listing of `_state/_datasets/`."""
        return self._names(f"{STATE}/{DATASET_INDEX}", "directory")

    def _names(self, folder: str, kind: str) -> list[str]:
        key = self.store.key(folder)
        self.store.fs.invalidate_cache(key)  # s3fs caches listings: a stage committed since must show
        try:
            entries = self.store.fs.ls(key, detail=True)
        except FileNotFoundError:
            return []
        names = (e["name"].rstrip("/").rsplit("/", 1)[-1] for e in entries if e.get("type") == kind)
        return sorted(name for name in names if is_plain_name(name))  # a name that is no plain name is never followed

    # ----------------------------------------------------------------------------------- damage
    def check(self, marker: Marker, verify: bool) -> list[Damage]:
        """Objects are checked only with `verify`: every object's size (one listing of the attempt prefix)
        and CRC-32C (each object read once)."""
        if not verify:
            return []
        keys = {entry.path: self.store.key(marker.keys.get(entry.path, entry.path)) for entry in marker.files}
        listed = self._listed_sizes(list(keys.values()))
        found = []
        for entry in marker.files:
            key = keys[entry.path]
            size = listed.get(key.lstrip("/"))
            if size is None:
                found.append(Damage(marker.stage, marker.unit, entry.path, "is missing on the store"))
            elif size != entry.size:
                found.append(Damage(marker.stage, marker.unit, entry.path, f"has {size} bytes, the marker says {entry.size}"))
            elif f"{google_crc32c.value(self.store.fs.cat_file(key)):08x}" != entry.crc32c:
                found.append(Damage(marker.stage, marker.unit, entry.path, f"fails its checksum (crc32c {entry.crc32c})"))
        return found

    def _listed_sizes(self, keys: list[str]) -> dict[str, int]:
        """Key -> size of the objects below the keys' common prefix (a unit's attempt prefix): one listing."""
        if not keys:
            return {}
        common = keys[0].rsplit("/", 1)[0]
        while not all(k.startswith(f"{common}/") for k in keys):
            common = common.rsplit("/", 1)[0]
        self.store.fs.invalidate_cache(common)
        try:
            listed = self.store.fs.find(common, detail=True)
        except FileNotFoundError:
            return {}
        return {name.lstrip("/"): int(info.get("size") or 0) for name, info in listed.items()}

    def recorded_damage(self, markers: list[Marker]) -> list[list[Damage]]:
        """The damage noted for each marker: one read of each stage's notes object."""
        notes = {stage: self._damage_notes(stage) for stage in {m.stage for m in markers}}
        return [_noted_damage(m, notes[m.stage].get(m.unit), f"{STATE}/{m.stage}/{DAMAGE_NOTES}") for m in markers]

    def _damage_notes(self, stage: str) -> dict[str, dict]:
        """Unit -> note of the stage's damage notes object ({} when there is none or it is unreadable)."""
        text = self.store.read_text(f"{STATE}/{stage}/{DAMAGE_NOTES}")
        if not text:
            return {}
        try:
            notes = json.loads(text)
            return notes if isinstance(notes, dict) else {}
        except ValueError:
            log.warning("%s: unreadable damage notes of stage %s ignored", self.location, stage)
            return {}

    def update_damage(self, stage: str, damaged: Iterable[tuple[Marker, list[Damage]]] = (),
                      cleared: Iterable[str] = ()) -> None:
        """Record damage of some units of a stage and forget that of others, in one read and one write."""
        notes = self._damage_notes(stage)
        before = dict(notes)
        for unit in cleared:
            notes.pop(unit, None)
        for marker, problems in damaged:
            notes[marker.unit] = _note(marker, problems)
        if notes == before:
            return
        try:
            self.store.put_text(f"{STATE}/{stage}/{DAMAGE_NOTES}", json.dumps(notes, indent=1, sort_keys=True))
        except OSError as error:
            log.warning("%s: cannot record damage of stage %s: %s", self.location, stage, error)

    # -------------------------------------------------------------------------- committed files
    def path_of(self, marker: Marker, relative: str) -> str:
        """The URL a file or Zarr store committed by `marker` is read at (the key its marker names)."""
        if relative in marker.keys:
            return self.store.url_of(marker.keys[relative])
        metadata = marker.keys.get(f"{relative}/zarr.json")  # a Zarr store: the folder of its metadata
        if metadata is None:
            raise KeyError(f"{marker.stage}/{marker.unit} committed no {relative}")
        return self.store.url_of(metadata.rsplit("/", 1)[0])

    def read_part(self, location: Path | str, schema: pa.Schema, **options: Any) -> pa.Table:
        # One GET of the whole part: through a file system pyarrow asks for the size, opens, then reads the
        # footer and the data by ranges (4 requests a part; each costs more than a small part's bytes).
        return pq.read_table(pa.BufferReader(self.store.fs.cat_file(str(location))), schema=schema, **options)

    def commit(self, stage: str, unit: str, staging: Path, files: list[OutputFile], outputs: list[str],
               previous: Marker | None) -> dict[str, str]:
        """Upload the staged files under keys unique to this unit and attempt; logical path -> key.

        Nothing is renamed: a reader finds these keys only through the marker written after them, so an
        attempt that dies here (or whose upload fails) leaves objects no marker names.
        """
        base = f"{ATTEMPTS}/{stage}/{unit}/{attempt_id()}"
        keys = {entry.path: f"{base}/{entry.path}" for entry in files}
        self.store.put_files([(staging / path, key) for path, key in keys.items()])
        shutil.rmtree(staging, ignore_errors=True)
        return keys

    def forget(self, previous: Marker, keys: dict[str, str]) -> None:
        """Delete the previous attempt's objects, now named by no marker."""
        self.store.remove(sorted(set(previous.keys.values()) - set(keys.values())))

    def retire(self, marker: Marker) -> None:
        self.store.remove(sorted(marker.keys.values()))

    def upload_log(self, stage: str, unit: str, local: Path) -> None:
        """Copy a unit's log to the store (best effort: a log is not an output)."""
        try:
            self.store.put_file(local, f"logs/{stage}/{unit}.log")
        except Exception as error:  # noqa: BLE001 - an outage raises botocore's or aiohttp's errors, no OSError
            log.warning("%s: log of %s/%s not uploaded (%s: %s)", self.location, stage, unit, type(error).__name__,
                        error_text(error))

    # ------------------------------------------------------------------------------------- lock
    def lock(self) -> RemoteRunLock:
        return RemoteRunLock(self.store)

    def lock_holder(self) -> dict | None:
        found = self.store.read_object(LOCK_KEY)
        return parse_holder(found.data) if found is not None else None


RunFiles = LocalFiles | StoreFiles


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None


def _blocked_outputs(outputs: list[str], files: set[str],
                     folder_problem: Callable[[str], str | None]) -> dict[str, str]:
    """Output (a file, or a folder such as a Zarr store, with a '/' after it) -> why it is not reached through
    real folders only, for the outputs that are not."""
    blocked = {}
    for output in outputs:
        is_file = output in files
        problem = folder_problem(output.rpartition("/")[0] if is_file else output)
        if problem is not None:
            blocked[output if is_file else f"{output}/"] = problem
    return blocked


def _is_file(path: Path) -> bool:
    """True when `path` is a regular file itself (a link is not followed)."""
    try:
        return S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False

