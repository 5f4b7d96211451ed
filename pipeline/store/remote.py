"""Run folders on object storage (any fsspec URL: `s3://bucket/prefix`, `gs://...`, `memory://...`): the
store's side of `pipeline.store.backends.StoreFiles`.

A remote run lives on its store and is read there. Units stage on local disk as they do for a local run
(in a local folder per URL, `cache_folder`, which holds only the job file, staging, logs before upload and
the lock's guard); at commit their files are uploaded under keys unique to the unit and attempt
(`_attempts/<stage>/<unit>/<attempt id>/<logical path>`), then the marker, last. The marker keeps the
logical paths (`videos/<emb>/<video>.zarr/...`, `<dataset>/part-<unit>.parquet`) in `files` and maps each
to its key in `keys`, so tables and file bytes are those of a local run and a reader trusts only keys a
marker names: an attempt that died uploaded under keys nobody names. Readers read those keys in place
(pyarrow, DuckDB and Zarr through the same fsspec client); nothing but markers is listed. Stores have no
rename, so nothing is renamed there.

Credentials come only from the environment or the usual config files (fsspec/s3fs/botocore read them);
no option holding one is ever taken from the command line or written anywhere by this module.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any, NamedTuple

import fsspec
import fsspec.asyn
from fsspec.implementations.memory import MemoryFileSystem

from pipeline.errors import error_text
from pipeline.store.names import REMOTE_FILE

log = logging.getLogger(__name__)

_URL = re.compile(r"^([a-z][a-z0-9+.-]+):/+(.*)$")
# Variables a Ray worker needs to reach the same store as the driver: handed to its tasks as an argument
# (held in memory by Ray, never in a runtime_env, which Ray writes into its logs), never written down.
STORAGE_ENVIRONMENT = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN", "AWS_ENDPOINT_URL",
                       "AWS_ENDPOINT_URL_S3", "AWS_DEFAULT_REGION", "AWS_REGION", "AWS_PROFILE",
                       "AWS_SHARED_CREDENTIALS_FILE", "AWS_CONFIG_FILE", "GOOGLE_APPLICATION_CREDENTIALS",
                       "MVPD_CACHE_DIR")


def storage_environment(url: str | None) -> dict[str, str]:
    """The driver's storage variables (endpoint, credentials) for the workers of a run on `url` ({} locally)."""
    if url is None:
        return {}
    return {name: os.environ[name] for name in STORAGE_ENVIRONMENT if name in os.environ}


def use_storage_environment(environment: dict[str, str]) -> None:
    """In a Ray worker: take the driver's storage variables (a task argument) before the store is opened.

    s3fs keeps one client per set of options, not per environment: when a variable changes, the cached
    clients are dropped so the next one is made with the driver's endpoint and credentials.
    """
    if all(os.environ.get(name) == value for name, value in environment.items()):
        return
    os.environ.update(environment)
    for module in ("s3fs", "gcsfs"):
        loaded = sys.modules.get(module)
        if loaded is not None:
            for filesystem in (getattr(loaded, "S3FileSystem", None), getattr(loaded, "GCSFileSystem", None)):
                if filesystem is not None:
                    filesystem.clear_instance_cache()


class StoreError(OSError):
    """An object store that cannot be used (no such bucket, refused credentials, unreachable endpoint)."""


def remote_url(location: str | os.PathLike) -> str | None:
    """The normalized URL when `location` names an object store, None for a local path (`file://` included).

    A `pathlib.Path` collapses `s3://b/p` into `s3:/b/p`; both spellings are accepted.
    """
    match = _URL.match(str(location))
    if match is None or match.group(1) in ("file", "local"):
        return None
    return f"{match.group(1)}://{match.group(2).rstrip('/')}"


def local_path(location: str | os.PathLike) -> Path:
    """A local path from a path or a `file://` URL."""
    match = _URL.match(str(location))
    return Path(f"/{match.group(2)}") if match and match.group(1) in ("file", "local") else Path(location)


def cache_folder(url: str) -> Path:
    """The local folder of a remote run (`MVPD_CACHE_DIR`, default ~/.cache/mvpd/runs), one per URL: staging and logs."""
    base = Path(os.environ.get("MVPD_CACHE_DIR") or Path.home() / ".cache" / "mvpd" / "runs")
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", url.split("://", 1)[1])[-60:]
    return base / f"{name}-{hashlib.sha256(url.encode()).hexdigest()[:12]}"


def working_copy_url(root: Path) -> str | None:
    """The URL a local folder stands for (None for an ordinary local run folder)."""
    try:
        return (Path(root) / REMOTE_FILE).read_text(encoding="utf-8").strip() or None
    except (FileNotFoundError, NotADirectoryError):
        return None


def attempt_id() -> str:
    """Unique per attempt of a unit: host, process and time (two attempts never share a key)."""
    return f"{socket.gethostname()}.{os.getpid()}.{time.time_ns()}"


class RunStore:
    """The object-store side of a remote run folder: an fsspec filesystem rooted at the run's prefix.

    Every key is relative to the run (as in datatrove's DataFolder), so no caller joins URLs.
    """

    def __init__(self, url: str):
        self.url = url
        self.fs, self.prefix = fsspec.core.url_to_fs(url)
        self.prefix = self.prefix.rstrip("/")

    def key(self, relative: str) -> str:
        return f"{self.prefix}/{relative}" if self.prefix else relative

    def url_of(self, relative: str) -> str:
        """The full URL of a key of the run (`s3://bucket/prefix/<relative>`), as DuckDB and Zarr open it."""
        return self.fs.unstrip_protocol(self.key(relative))

    def check(self) -> None:
        """Fail with one line when the bucket is missing, the credentials are refused or the endpoint is down."""
        bucket = self.prefix.split("/", 1)[0]
        try:
            if not isinstance(self.fs, MemoryFileSystem):  # the memory store of the tests has no buckets
                self._probe().info(bucket)
        except PermissionError as error:
            raise StoreError(f"{self.url}: access refused ({error_text(error)}); check the credentials in the "
                             "environment (AWS_ACCESS_KEY_ID/AWS_SECRET_ACCESS_KEY) or ~/.aws") from None
        except FileNotFoundError:
            raise StoreError(f"{self.url}: bucket {bucket!r} does not exist; create it or fix the URL") from None
        except (OSError, ValueError) as error:
            raise StoreError(f"{self.url}: the object store cannot be reached ({error_text(error)}); check the "
                             "endpoint (AWS_ENDPOINT_URL) and the network") from None
        except Exception as error:  # noqa: BLE001 - botocore raises its own types (EndpointConnectionError, ...)
            raise StoreError(f"{self.url}: the object store cannot be used ({type(error).__name__}: "
                             f"{error_text(error)}); check the endpoint and the credentials") from None

    def _probe(self) -> fsspec.AbstractFileSystem:
        """A filesystem like ours that fails fast: one try, a short connect timeout (S3 only; else ours)."""
        if "s3" not in self.fs.protocol:
            return self.fs
        options = {**self.fs.storage_options, "skip_instance_cache": True,
                   "config_kwargs": {"retries": {"max_attempts": 1, "mode": "standard"}, "connect_timeout": 5}}
        return type(self.fs)(**options)

    def exists(self, relative: str) -> bool:
        return self.fs.exists(self.key(relative))

    def put_file(self, local: Path, relative: str) -> None:
        self.fs.put_file(str(local), self.key(relative))

    def put_files(self, uploads: list[tuple[Path, str]]) -> None:
        """Upload many files at once (concurrent requests on an async store such as s3fs); any failure raises."""
        if uploads:
            self.fs.put([str(local) for local, _ in uploads], [self.key(relative) for _, relative in uploads])

    def put_text(self, relative: str, text: str) -> None:
        """One PUT: on an object store a reader sees the old object or the new one whole."""
        self.fs.pipe_file(self.key(relative), text.encode("utf-8"))

    def read_text(self, relative: str) -> str | None:
        try:
            return self.fs.cat_file(self.key(relative)).decode("utf-8")
        except FileNotFoundError:
            return None

    def remove(self, relatives: list[str]) -> None:
        """Delete keys (best effort: a key left behind is named by no marker, so no reader sees it)."""
        for relative in relatives:
            try:
                self.fs.rm_file(self.key(relative))
            except FileNotFoundError:
                pass
            except OSError as error:
                log.warning("%s: could not delete %s (%s); it is named by no marker", self.url, relative, error)

    def marker_texts(self, folder: str) -> dict[str, str]:
        """Relative path -> text of every `*.json` below `folder` (one listing, one batched fetch)."""
        base = self.key(folder)
        try:
            keys = [k for k in self.fs.find(base) if k.endswith(".json")]
        except FileNotFoundError:
            return {}
        if not keys:
            return {}
        fetched: dict[str, Any] = self.fs.cat(keys, on_error="omit")
        start = len(self.key("")) if self.prefix else 0
        return {k[start:].lstrip("/"): v.decode("utf-8") for k, v in fetched.items() if isinstance(v, bytes)}

    # ------------------------------------------------ conditional writes (the run lock) and listing (gc)
    def create_object(self, relative: str, data: bytes) -> str | None:
        """Write `relative` only when no object is there (S3 `If-None-Match: *`); its tag, or None when one is.

        On S3 the store checks the condition, so of two writers racing on one key exactly one wins.
        """
        key = self.key(relative)
        if not _is_s3(self.fs):
            with _EMULATED_CONDITIONS:
                if self.fs.exists(key):
                    return None
                self.fs.pipe_file(key, data)
                return _content_tag(data)
        try:
            response = self.fs.pipe_file(key, data, mode="create")
        except OSError as error:
            if _lost_a_condition(error):
                return None
            raise
        return str(response["ETag"])

    def read_object(self, relative: str) -> StoredObject | None:
        """The object's bytes, tag and modification time from one GET (they belong together); None if absent."""
        key = self.key(relative)
        if not _is_s3(self.fs):
            with _EMULATED_CONDITIONS:
                try:
                    data = self.fs.cat_file(key)
                except FileNotFoundError:
                    return None
                return StoredObject(data, _content_tag(data), _modified(self.fs.info(key)))
        bucket, name, _ = self.fs.split_path(key)
        try:
            return fsspec.asyn.sync(self.fs.loop, _s3_get, self.fs, bucket, name)
        except FileNotFoundError:
            return None

    def replace_object(self, relative: str, data: bytes, tag: str) -> str | None:
        """Overwrite `relative` only while its tag is still `tag` (S3 `If-Match`); the new tag, or None when
        another writer changed or removed it since `tag` was read."""
        key = self.key(relative)
        if not _is_s3(self.fs):
            with _EMULATED_CONDITIONS:
                if self._emulated_tag(key) != tag:
                    return None
                self.fs.pipe_file(key, data)
                return _content_tag(data)
        try:
            response = self.fs.pipe_file(key, data, IfMatch=tag)
        except OSError as error:
            if isinstance(error, FileNotFoundError) or _lost_a_condition(error):
                return None
            raise
        return str(response["ETag"])

    def remove_object(self, relative: str, tag: str) -> bool:
        """Delete `relative` only while its tag is still `tag` (S3 `If-Match` on DELETE); False otherwise."""
        key = self.key(relative)
        if not _is_s3(self.fs):
            with _EMULATED_CONDITIONS:
                if self._emulated_tag(key) != tag:
                    return False
                self.fs.rm_file(key)
                return True
        bucket, name, _ = self.fs.split_path(key)
        try:
            self.fs.call_s3("delete_object", Bucket=bucket, Key=name, IfMatch=tag)
        except OSError as error:
            if isinstance(error, FileNotFoundError) or _lost_a_condition(error):
                return False
            raise
        finally:
            self.fs.invalidate_cache(key)
        return True

    def _emulated_tag(self, key: str) -> str | None:
        """The content tag of `key` on a store without conditions (None when absent); hold _EMULATED_CONDITIONS."""
        try:
            return _content_tag(self.fs.cat_file(key))
        except FileNotFoundError:
            return None

    def list_objects(self, folder: str) -> dict[str, int]:
        """Relative key -> size of every object below `folder` (a listing: for gc, never a hot path)."""
        try:
            found = self.fs.find(self.key(folder), detail=True)
        except FileNotFoundError:
            return {}
        start = len(self.key("")) if self.prefix else 0
        return {name[start:].lstrip("/"): int(entry.get("size") or 0) for name, entry in found.items()
                if entry.get("type") != "directory"}

    def delete_objects(self, relatives: list[str]) -> None:
        """Delete many keys in one batched call (S3 DeleteObjects takes up to 1000 per request); raises on failure."""
        if relatives:
            self.fs.rm([self.key(relative) for relative in relatives])


class StoredObject(NamedTuple):
    """An object's bytes, the version tag conditional writes compare (S3: its ETag) and its age."""

    data: bytes
    tag: str
    modified: float  # seconds since the epoch, by the store's clock


# A store without native conditions (memory://, whose objects live in this process): compare-and-swap under
# one process-wide lock is then exactly atomic. (Other stores would keep a window between read and write;
# only s3:// and memory:// run folders are supported for the lock's guarantees, see the README.)
_EMULATED_CONDITIONS = threading.Lock()


def _is_s3(fs: fsspec.AbstractFileSystem) -> bool:
    protocols = (fs.protocol,) if isinstance(fs.protocol, str) else fs.protocol
    return "s3" in protocols


def _content_tag(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _modified(info: dict[str, Any]) -> float:
    stamp = info.get("LastModified") or info.get("created") or info.get("mtime") or 0.0
    return stamp.timestamp() if hasattr(stamp, "timestamp") else float(stamp)


def _lost_a_condition(error: OSError) -> bool:
    """True for a failed precondition: s3fs raises FileExistsError for `If-None-Match`, and an OSError caused by
    botocore's 412 PreconditionFailed for `If-Match`; S3 answers 409 ConditionalRequestConflict to a
    conditional write racing another one. (s3fs's errno, EINVAL, is shared by many unrelated errors.)"""
    if isinstance(error, FileExistsError):
        return True
    response = getattr(error.__cause__, "response", None) or {}
    code = response.get("Error", {}).get("Code")
    status = response.get("ResponseMetadata", {}).get("HTTPStatusCode")
    return code in ("PreconditionFailed", "ConditionalRequestConflict") or status in (409, 412)


async def _s3_get(fs: Any, bucket: str, name: str) -> StoredObject:
    """One GET on s3fs's event loop: body, ETag and LastModified of the same version of the object."""
    from s3fs.errors import translate_boto_error
    from botocore.exceptions import ClientError

    try:
        response = await fs._call_s3("get_object", Bucket=bucket, Key=name)
    except ClientError as error:
        raise translate_boto_error(error) from None
    async with response["Body"] as body:
        data = await body.read()
    return StoredObject(data, str(response["ETag"]), response["LastModified"].timestamp())
