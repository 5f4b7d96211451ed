"""The markers of a run on object storage, read where they are: no local copy of the run is made.

`pipeline.runtime.markers` hands its work here when the folder it is given stands for a store (a
`.remote-url`, see `object_store.store_of`). What differs from local disk (schemas/README.md, "On object
storage"):

- Markers come from the stage's marker index and one listing of `_state/<stage>/`
  (`marker_index.marker_folder`).
- Objects are written whole by one PUT each, before their marker, and never changed: `status` does not
  ask the store about each of a unit's ~40 objects (0.7 M requests at MVPd scale). It reports the damage
  a verify or a reader recorded; `status --verify` lists each unit's attempt prefix (sizes) and reads
  every object (CRC-32C).
- Damage notes of a stage are one object, `_state/<stage>/_damage.notes` ({unit: note}), so `status`
  reads one object per stage, not one per unit. Two writers at once may lose a note; the next verify
  finds the damage again (a note only speeds repair up).
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict

import google_crc32c

from pipeline.runtime.markers import DATASET_INDEX, STATE, Damage, Marker, is_plain_name, parse_marker
from pipeline.runtime.object_store import RunStore

log = logging.getLogger(__name__)

DAMAGE_NOTES = "_damage.notes"


def unit_marker(store: RunStore, stage: str, unit: str) -> Marker | None:
    """One unit's marker (one GET); None when it has none."""
    text = store.read_text(f"{STATE}/{stage}/{unit}.json")
    return parse_marker(text, f"{unit}.json") if text is not None else None


def stages_writing(store: RunStore, dataset: str) -> list[str]:
    """Stages with committed parts of `dataset`: one listing of `_state/_datasets/<dataset>/`."""
    return _names(store, f"{STATE}/{DATASET_INDEX}/{dataset}", "file")


def marked_stages(store: RunStore) -> list[str]:
    """Stages with a marker folder on the store: one listing of `_state/`."""
    return [name for name in _names(store, STATE, "directory") if name != DATASET_INDEX]


def indexed_datasets(store: RunStore) -> list[str]:
    """Datasets some stage has committed parts of: one listing of `_state/_datasets/`."""
    return _names(store, f"{STATE}/{DATASET_INDEX}", "directory")


def _names(store: RunStore, folder: str, kind: str) -> list[str]:
    key = store.key(folder)
    store.fs.invalidate_cache(key)  # s3fs caches listings: a stage committed since must show
    try:
        entries = store.fs.ls(key, detail=True)
    except FileNotFoundError:
        return []
    names = (e["name"].rstrip("/").rsplit("/", 1)[-1] for e in entries if e.get("type") == kind)
    return sorted(name for name in names if is_plain_name(name))  # a name that is no plain name is never followed


# ------------------------------------------------------------------------------------- checking


def check_files(store: RunStore, marker: Marker, verify: bool, notes: dict[str, dict] | None) -> list[Damage]:
    """Problems of one unit on the store: recorded damage (`notes`, None to skip), and with `verify` every
    object's size (one listing of the attempt prefix) and CRC-32C (each object read once)."""
    found = recorded_damage(marker, notes) if notes is not None else []
    if verify:
        found = _verify(store, marker) + found
    return found


def _verify(store: RunStore, marker: Marker) -> list[Damage]:
    keys = {entry.path: store.key(marker.keys.get(entry.path, entry.path)) for entry in marker.files}
    listed = _listed_sizes(store, list(keys.values()))
    found = []
    for entry in marker.files:
        key = keys[entry.path]
        size = listed.get(key.lstrip("/"))
        if size is None:
            found.append(Damage(marker.stage, marker.unit, entry.path, "is missing on the store"))
        elif size != entry.size:
            found.append(Damage(marker.stage, marker.unit, entry.path, f"has {size} bytes, the marker says {entry.size}"))
        elif f"{google_crc32c.value(store.fs.cat_file(key)):08x}" != entry.crc32c:
            found.append(Damage(marker.stage, marker.unit, entry.path, f"fails its checksum (crc32c {entry.crc32c})"))
    return found


def _listed_sizes(store: RunStore, keys: list[str]) -> dict[str, int]:
    """Key -> size of the objects below the keys' common prefix (a unit's attempt prefix): one listing."""
    if not keys:
        return {}
    common = keys[0].rsplit("/", 1)[0]
    while not all(k.startswith(f"{common}/") for k in keys):
        common = common.rsplit("/", 1)[0]
    store.fs.invalidate_cache(common)
    try:
        listed = store.fs.find(common, detail=True)
    except FileNotFoundError:
        return {}
    return {name.lstrip("/"): int(info.get("size") or 0) for name, info in listed.items()}


# --------------------------------------------------------------------------------- damage notes


def damage_notes(store: RunStore, stage: str) -> dict[str, dict]:
    """Unit -> note of the stage's damage notes object ({} when there is none or it is unreadable)."""
    text = store.read_text(f"{STATE}/{stage}/{DAMAGE_NOTES}")
    if not text:
        return {}
    try:
        notes = json.loads(text)
        return notes if isinstance(notes, dict) else {}
    except ValueError:
        log.warning("%s: unreadable damage notes of stage %s ignored", store.url, stage)
        return {}


def recorded_damage(marker: Marker, notes: dict[str, dict]) -> list[Damage]:
    """The damage `notes` record for this very marker (a unit committed again since has none)."""
    note = notes.get(marker.unit)
    try:
        if not note or note["finished_at"] != marker.finished_at:
            return []
        return [Damage(**p) for p in note["problems"]]
    except (TypeError, KeyError):
        return [Damage(marker.stage, marker.unit, f"{STATE}/{marker.stage}/{DAMAGE_NOTES}", "is an unreadable damage note")]


def update_damage(store: RunStore, stage: str, damaged: list[tuple[Marker, list[Damage]]] = (),
                  cleared: list[str] = ()) -> None:
    """Record damage of some units of a stage and forget that of others, in one read and one write."""
    notes = damage_notes(store, stage)
    before = dict(notes)
    for unit in cleared:
        notes.pop(unit, None)
    for marker, problems in damaged:
        notes[marker.unit] = {"finished_at": marker.finished_at, "problems": [asdict(p) for p in problems]}
    if notes == before:
        return
    try:
        store.put_text(f"{STATE}/{stage}/{DAMAGE_NOTES}", json.dumps(notes, indent=1, sort_keys=True))
    except OSError as error:
        log.warning("%s: cannot record damage of stage %s: %s", store.url, stage, error)
