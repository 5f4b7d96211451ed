"""A consolidated index of one stage's markers: a cache of `_state/<stage>/*.json` in one Parquet file.

The markers stay the commit points and the only truth (schemas/README.md, "Commit protocol"). Reading
18,000 marker files of ~15 kB each (a full-scale render stage) costs seconds on local disk and 18,000
GETs on an object store; the index `_state/<stage>/_index.parquet` holds them all in one file.

Each index row records the *identity* of the marker file it was taken from (local: size, mtime in ns and
inode; an object store: size and ETag or last-modified time, from the listing). A reader lists the marker
folder once (one readdir, or one paginated LIST), takes from the index the markers whose identity matches
the listing, reads only the others, and drops rows whose marker is gone. An index that cannot be read,
has another schema or version, or is missing, is ignored and rebuilt, never trusted.

Why a stale or racing index is harmless: the listing is taken before any marker is read, so a row pairs
a marker's content with an identity no newer than that content; a marker rewritten later has a new
identity (an atomic rename makes a new inode, a PUT a new ETag) and is read again. The index is replaced
whole (rename locally, one PUT on a store), so two writers leave one complete index, each row of which
is right for the identity it records.
"""

from __future__ import annotations

import io
import json
import logging
import os
from dataclasses import fields
from pathlib import Path
from typing import Any, Protocol

import fsspec
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from pipeline.errors import error_text
from pipeline.store.markers import ColumnarManifest, Marker, marker_problem, parse_marker
import pipeline.store.links as links
from pipeline.store.names import RUN_PATH, STATE, RunFolderError

log = logging.getLogger(__name__)

INDEX_NAME = "_index.parquet"
INDEX_VERSION = 1
MARKER_SUFFIX = ".json"
_READ = os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC
# What reading markers and the index may cost at most (a full-scale render stage: 18,000 markers of ~15 kB
# and ~40 files each, an index of ~100 MB decoded): beyond these a file is unreadable, not a memory bill.
MAX_MARKER_BYTES = 16 * 2**20
MAX_INDEX_BYTES = 2**30
MAX_INDEX_VALUES = 100_000_000
# A reader that had to read at least this many markers itself (or drop this many rows) rewrites the
# index when it can, so the next reader does not (fewer, and the driver's write at stage end suffices).
REFRESH_AFTER = 256
INDEX_SCHEMA = pa.schema(
    [
        pa.field("name", pa.string(), nullable=False),  # the marker's file name, `<unit>.json`
        pa.field("identity", pa.string(), nullable=False),  # the marker file's identity when read
        pa.field("header", pa.string()),  # the marker's JSON without `files`; null: not a valid marker
        pa.field("file_path", pa.list_(pa.string())),  # the manifest, column by column
        pa.field("file_size", pa.list_(pa.int64())),
        pa.field("file_crc32c", pa.list_(pa.string())),
    ],
    metadata={"mvpd_marker_index": str(INDEX_VERSION)},
)


class MarkerFolder(Protocol):
    """Where one stage's markers live: a local folder or a prefix of an object store."""

    def listing(self) -> dict[str, str]:
        """Marker file name (`<unit>.json`) -> identity of the file, from one listing of the folder."""

    def read_texts(self, names: list[str]) -> dict[str, str]:
        """Name -> text of the named marker files (a file gone since the listing is left out)."""

    def read_index(self) -> bytes | None:
        """The index file's bytes, None when there is none."""

    def write_index(self, data: bytes) -> None:
        """Replace the index file atomically (raises OSError when the folder is read-only)."""


class LocalMarkerFolder:
    """The marker folder `_state/<stage>` of a run folder on local disk, reached and read through no link
    (`pipeline.store.links`): a marker that is a link or a folder is read as an unreadable marker (its unit
    is not done, and its commit replaces it), and a link on the way to the folder lists nothing."""

    def __init__(self, root: Path | str, stage: str):
        self.root = os.fspath(root)
        self.relative = f"{STATE}/{stage}"
        self.folder = os.path.join(self.root, STATE, stage)

    def listing(self) -> dict[str, str]:
        found = {}
        try:
            with links.folder(self.root, self.relative) as descriptor, os.scandir(descriptor) as entries:
                for entry in entries:
                    name = entry.name
                    if name.endswith(MARKER_SUFFIX) and not name.startswith("."):
                        try:
                            info = entry.stat(follow_symlinks=False)
                        except FileNotFoundError:
                            continue  # removed since readdir
                        # A marker is replaced by rename, so a rewrite always changes the inode, even
                        # within one tick of the file-system clock.
                        found[name] = f"{info.st_size}:{info.st_mtime_ns}:{info.st_ino}"
        except (FileNotFoundError, links.RunLinkError):
            return {}
        return found

    def read_texts(self, names: list[str]) -> dict[str, str]:
        texts = {}
        if not names:
            return texts
        try:
            with links.folder(self.root, self.relative) as descriptor:
                for name in names:
                    try:
                        with open(os.open(name, _READ, dir_fd=descriptor), "rb") as handle:
                            too_big = os.fstat(handle.fileno()).st_size > MAX_MARKER_BYTES
                            texts[name] = "" if too_big else handle.read().decode("utf-8")
                    except FileNotFoundError:
                        continue
                    except (UnicodeDecodeError, OSError):  # a folder, a link (ELOOP), bad bytes: no marker
                        texts[name] = ""
        except (FileNotFoundError, links.RunLinkError):
            return {}
        return texts

    def read_index(self) -> bytes | None:
        try:
            return links.read_bytes(self.root, f"{self.relative}/{INDEX_NAME}")
        except (OSError, links.RunLinkError):  # missing, a folder, a link: no index (rebuilt, which replaces it)
            return None

    def write_index(self, data: bytes) -> None:
        links.write_file(self.root, f"{self.relative}/{INDEX_NAME}", data)


class FsspecMarkerFolder:
    """The marker folder of a stage on any fsspec file system (`s3://...`, `memory://...`).

    One listing (S3: a paginated LIST, 1,000 keys a page) gives every marker's size and ETag; the markers
    the index lacks are fetched in one batch; the index is written by one PUT (atomic on object stores).
    """

    def __init__(self, fs: fsspec.AbstractFileSystem, folder: str):
        self.fs = fs
        self.folder = folder.rstrip("/")

    def listing(self) -> dict[str, str]:
        self.fs.invalidate_cache(self.folder)  # s3fs caches listings; a stale one would hide new markers
        try:
            entries = self.fs.ls(self.folder, detail=True)
        except FileNotFoundError:
            return {}
        found = {}
        for entry in entries:
            name = entry["name"].rstrip("/").rsplit("/", 1)[-1]
            if entry.get("type") == "file" and name.endswith(MARKER_SUFFIX) and not name.startswith("."):
                found[name] = f"{entry.get('size')}:{_version_of(entry)}"
        return found

    def read_texts(self, names: list[str]) -> dict[str, str]:
        if not names:
            return {}
        paths = {f"{self.folder}/{name}": name for name in names}
        fetched: dict[str, Any] = self.fs.cat(list(paths), on_error="omit")
        texts = {}
        for path, data in fetched.items():
            name = paths.get(path) or paths.get(path.lstrip("/")) or path.rsplit("/", 1)[-1]
            if isinstance(data, bytes):
                texts[name] = data.decode("utf-8", errors="replace")
        return texts

    def read_index(self) -> bytes | None:
        try:
            return self.fs.cat_file(f"{self.folder}/{INDEX_NAME}")
        except FileNotFoundError:
            return None

    def write_index(self, data: bytes) -> None:
        self.fs.pipe_file(f"{self.folder}/{INDEX_NAME}", data)


def _version_of(entry: dict[str, Any]) -> str:
    """What changes when an object is rewritten: its ETag (S3, GCS), else its modification time."""
    for key in ("ETag", "etag", "md5Hash", "generation", "LastModified", "mtime", "last_modified", "created"):
        if entry.get(key) is not None:
            return str(entry[key])
    return ""


# ---------------------------------------------------------------------------------- reading


def load_markers(folder: MarkerFolder, refresh: bool = True, unreadable: list[str] | None = None) -> dict[str, Marker]:
    """Every valid marker of the folder by unit id, as reading every marker file would give them.

    Markers the index holds under their current identity come from the index; the others are read.
    `unreadable`, when given, receives the names of marker files that are no valid marker.
    With `refresh`, an index with many stale rows (or none, for a big folder) is rewritten when the
    folder is writable; a read-only run folder is simply read as it is.
    """
    rows, stale = _current_rows(folder)
    if unreadable is not None:  # file names of markers that are no valid marker (damaged, a folder, a link)
        unreadable.extend(name for name, (_, marker) in sorted(rows.items()) if marker is None)
    if refresh and stale >= REFRESH_AFTER:
        try:
            folder.write_index(_encode(rows))
        except (OSError, RunFolderError) as error:  # read-only: the markers were read; the next reader reads them again
            log.debug("marker index not written (%s)", error)
    return {marker.unit: marker for _, (_, marker) in sorted(rows.items()) if marker is not None}


def write_index(folder: MarkerFolder) -> int:
    """Bring the folder's index up to date (the driver, at the end of a stage run); how many markers it holds."""
    rows, stale = _current_rows(folder)
    if stale:  # a missing index counts every marker as stale; an empty folder needs none
        folder.write_index(_encode(rows))
    return sum(marker is not None for _, marker in rows.values())


def _current_rows(folder: MarkerFolder) -> tuple[dict[str, tuple[str, Marker | None]], int]:
    """Name -> (identity, marker or None) of every marker file listed now, and how many index rows were
    stale (markers read because the index lacked them at their identity, plus rows of markers gone)."""
    listing = folder.listing()  # first: a row never pairs content with a newer identity (module docstring)
    cached = _read_rows(folder)
    rows = {name: row for name, row in cached.items() if listing.get(name) == row[0]}
    missing = sorted(set(listing) - set(rows))
    texts = folder.read_texts(missing)
    rows.update({name: (listing[name], parse_marker(texts[name], name)) for name in missing if name in texts})
    return rows, len(missing) + len(set(cached) - set(listing))


def _read_rows(folder: MarkerFolder) -> dict[str, tuple[str, Marker | None]]:
    """Name -> (identity, marker or None) from the index; empty when it is missing or cannot be trusted."""
    data = folder.read_index()
    if not data:
        return {}
    try:
        return _decode(data)
    except (pa.ArrowException, OSError, ValueError, TypeError, KeyError, RecursionError, MemoryError) as error:
        log.warning("marker index %s ignored and rebuilt: %s", getattr(folder, "folder", folder),
                    error_text(error))
        return {}


def _decode(data: bytes) -> dict[str, tuple[str, Marker | None]]:
    """The index's rows; the manifest is taken column by column (no Python object per Parquet cell)."""
    table = _bounded_table(data)
    if (table.schema.metadata or {}).get(b"mvpd_marker_index") != str(INDEX_VERSION).encode() or \
            not table.schema.equals(INDEX_SCHEMA):
        raise ValueError("not a marker index of this version")
    names = table.column("name").to_pylist()
    identities = table.column("identity").to_pylist()
    headers = table.column("header").to_pylist()
    paths, sizes, crcs = (table.column(c).combine_chunks() for c in ("file_path", "file_size", "file_crc32c"))
    if not (paths.offsets.equals(sizes.offsets) and paths.offsets.equals(crcs.offsets)):
        raise ValueError("the manifest columns disagree in length")
    offsets = paths.offsets.to_pylist()
    base = offsets[0] if offsets else 0
    paths, sizes, crcs = paths.flatten(), sizes.flatten(), crcs.flatten()
    tampered = _rows_with_bad_paths(paths, offsets)
    rows: dict[str, tuple[str, Marker | None]] = {}
    for index, (name, identity, header) in enumerate(zip(names, identities, headers)):
        if header is None:
            rows[name] = (identity, None)
            continue
        start, length = offsets[index] - base, offsets[index + 1] - offsets[index]
        marker = Marker(**json.loads(header))
        problem = ("a file path is not a plain relative path inside the run" if index in tampered
                   else marker_problem(marker, name, None))
        if problem is not None:  # never followed: the marker file is read (and judged) again instead
            log.warning("marker index row %s ignored: %s", name, problem)
            continue
        # The manifest stays columnar until someone asks for `files` (status needs only paths and sizes).
        del marker.files
        marker.__dict__["_manifest"] = ColumnarManifest(paths.slice(start, length), sizes.slice(start, length),
                                                        crcs.slice(start, length))
        rows[name] = (identity, marker)
    return rows


def _bounded_table(data: bytes) -> pa.Table:
    """The index's table, after checking from its footer that decoding stays within MAX_INDEX_BYTES and
    MAX_INDEX_VALUES (a forged footer or run-length code could otherwise make a few kilobytes decode to
    gigabytes); ValueError beyond them."""
    if len(data) > MAX_INDEX_BYTES:
        raise ValueError(f"the index file has {len(data)} bytes, more than {MAX_INDEX_BYTES}")
    parquet = pq.ParquetFile(io.BytesIO(data))
    meta = parquet.metadata
    chunks = [meta.row_group(g).column(c) for g in range(meta.num_row_groups) for c in range(meta.num_columns)]
    declared = sum(max(chunk.total_uncompressed_size, 0) for chunk in chunks)
    values = sum(max(chunk.num_values, 0) for chunk in chunks)
    if declared > MAX_INDEX_BYTES or values > MAX_INDEX_VALUES or meta.num_rows > MAX_INDEX_VALUES:
        raise ValueError(f"the index declares {declared} bytes and {values} values, more than an index holds")
    return parquet.read()


def _rows_with_bad_paths(paths: pa.Array, offsets: list[int]) -> set[int]:
    """Rows whose manifest holds a path that is not a plain relative path in the run (one vectorized match
    over every path of the index: a full-scale stage's index names 2 M files)."""
    valid = pc.match_substring_regex(paths, f"^(?:{RUN_PATH.pattern})$").fill_null(False)
    bad = np.flatnonzero(~valid.to_numpy(zero_copy_only=False))
    return set(np.searchsorted(np.asarray(offsets) - offsets[0], bad, side="right") - 1) if len(bad) else set()


def _encode(rows: dict[str, tuple[str, Marker | None]]) -> bytes:
    """The index file: one row per marker file, sorted by name."""
    columns: dict[str, list[Any]] = {field.name: [] for field in INDEX_SCHEMA}
    for name in sorted(rows):
        identity, marker = rows[name]
        columns["name"].append(name)
        columns["identity"].append(identity)
        if marker is None:
            for key in ("header", "file_path", "file_size", "file_crc32c"):
                columns[key].append(None)
            continue
        # Field by field, not `asdict`: that would make the `OutputFile`s of a marker still columnar.
        header = {f.name: getattr(marker, f.name) for f in fields(marker) if f.name != "files"}
        columns["header"].append(json.dumps(header, sort_keys=True))
        for key, values in zip(("file_path", "file_size", "file_crc32c"), _manifest_lists(marker)):
            columns[key].append(values)
    sink = io.BytesIO()
    pq.write_table(pa.table(columns, schema=INDEX_SCHEMA), sink, compression="zstd")
    return sink.getvalue()


def _manifest_lists(marker: Marker) -> tuple[list[str], list[int], list[str]]:
    """The marker's paths, sizes and checksums as three lists (from its columns when it still has them)."""
    manifest = marker.__dict__.get("_manifest")
    if isinstance(manifest, ColumnarManifest):
        return manifest.paths.to_pylist(), manifest.sizes.to_pylist(), manifest.crcs.to_pylist()
    return [f.path for f in marker.files], [f.size for f in marker.files], [f.crc32c for f in marker.files]
