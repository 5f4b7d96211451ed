"""A run folder on local disk is closed to links (schemas/README.md, "No links in a run folder").

Anyone who can write into a shared run folder can put a symbolic link where the run keeps its own folders
(`_staging -> ~/photos`); a command that followed it would read, write or delete outside the run. So
every write and delete below the run root goes through this module, which walks from the root one
component at a time with `O_NOFOLLOW | O_DIRECTORY` and works on the last folder's descriptor (`mkdirat`,
`openat`, `renameat`, `unlinkat`, and `shutil.rmtree(dir_fd=...)`, which never follows a link either): a
link (or a file) where a folder must be stops the operation with `RunLinkError`, one line naming it and the
repair, before anything changes. The final name of a write is replaced by rename (a link there is replaced,
never followed); a read opens its file with `O_NOFOLLOW`. The root itself is the folder the user named:
links above it are theirs.

Readers of committed files go through the markers' size check (`LocalFiles.check`), which `lstat`s each
file itself and the folders of each output (once per pass, `FolderCheck`); a reader of a video and `status
--verify` also check every folder inside its Zarr store. So a unit whose files pass through a link is
damaged and no reader is handed its paths. `run_links` lists the links among the run's own folders for
`mvpd status` and for a driver, which refuses to start on such a run.
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from pipeline.store.names import STAGING, STATE, RunFolderError

FOLDER_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
# The folders whose entries are the run's own folders (one level is listed below each by `run_links`).
OWN_FOLDERS = (STATE, STAGING, "logs", "videos", f"{STATE}/_datasets")


class RunLinkError(RunFolderError):
    """A path of the run passes through a symbolic link, or a file stands where a folder must be."""


def link_repair(root: Path | str, relative: str) -> str:
    """The one line that says a link sits inside the run and how to remove it (the link only)."""
    return (f"{root}/{relative} is a symbolic link inside the run folder; a run holds no links and none is "
            f"followed: remove it with `rm {root}/{relative}` (what it points to is kept), then run the "
            "command again")


def _refusal(root: Path | str, relative: str) -> RunLinkError:
    try:
        is_link = stat.S_ISLNK(os.lstat(os.path.join(root, relative)).st_mode)
    except OSError:
        is_link = False
    if is_link:
        return RunLinkError(link_repair(root, relative))
    return RunLinkError(f"{root}/{relative}: is not a folder, where the run keeps one; move it away "
                        f"(`mv {root}/{relative} {root}/{relative}.moved`), then run the command again")


def _parts(relative: str) -> list[str]:
    return [part for part in relative.split("/") if part]


@contextmanager
def folder(root: Path | str, relative: str, create: bool = False) -> Iterator[int]:
    """A descriptor of the folder `root/relative`, reached without following any link below `root`
    (created, folder by folder, with `create`); RunLinkError where a link or a file stands in the way,
    FileNotFoundError when a folder is missing and not created."""
    descriptor = os.open(root, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        walked = []
        for part in _parts(relative):
            walked.append(part)
            try:
                child = os.open(part, FOLDER_FLAGS, dir_fd=descriptor)
            except FileNotFoundError:
                if not create:
                    raise
                try:
                    os.mkdir(part, dir_fd=descriptor)
                except FileExistsError:  # made by another process meanwhile (or a dangling link: refused next)
                    pass
                child = _open_folder(root, walked, descriptor, part)
            except OSError as error:
                if error.errno in (errno.ELOOP, errno.ENOTDIR):
                    raise _refusal(root, "/".join(walked)) from None
                raise
            os.close(descriptor)
            descriptor = child
        yield descriptor
    finally:
        os.close(descriptor)


def _open_folder(root: Path | str, walked: list[str], parent: int, part: str) -> int:
    try:
        return os.open(part, FOLDER_FLAGS, dir_fd=parent)
    except OSError as error:
        if error.errno in (errno.ELOOP, errno.ENOTDIR, errno.ENOENT):
            raise _refusal(root, "/".join(walked)) from None
        raise


def make_folder(root: Path, relative: str) -> Path:
    """`root/relative`, created when missing, after checking that no link below `root` leads there."""
    with folder(root, relative, create=True):
        return root / relative


def remove(root: Path | str, relative: str) -> None:
    """Delete the file, link or folder tree `root/relative` (a link itself, never what it points to);
    nothing when it is not there. Folders on the way are never followed through a link (RunLinkError)."""
    parent, _, name = relative.rpartition("/")
    try:
        with folder(root, parent) as descriptor:
            try:
                info = os.lstat(name, dir_fd=descriptor)
            except FileNotFoundError:
                return
            if stat.S_ISDIR(info.st_mode):
                shutil.rmtree(name, dir_fd=descriptor, ignore_errors=True)  # as before: what cannot go stays
            else:
                os.unlink(name, dir_fd=descriptor)
    except FileNotFoundError:
        return


def replace(root: Path | str, source: str, target: str) -> None:
    """Rename `root/source` (a file or a folder) to `root/target`, replacing what is there: an old folder is
    moved aside and deleted, a file or a link is replaced (the link itself). Folders on the way to either are
    never followed through a link; the target's folders are created."""
    source_parent, _, source_name = source.rpartition("/")
    target_parent, _, target_name = target.rpartition("/")
    with folder(root, source_parent) as source_fd, folder(root, target_parent, create=True) as target_fd:
        _replace_at(source_fd, source_name, target_fd, target_name)


def _replace_at(source_fd: int, source_name: str, target_fd: int, target_name: str) -> None:
    """`replace` between two folder descriptors."""
    source_is_folder = stat.S_ISDIR(os.lstat(source_name, dir_fd=source_fd).st_mode)
    try:
        old = os.lstat(target_name, dir_fd=target_fd)
    except FileNotFoundError:
        old = None
    aside = None
    if old is not None and stat.S_ISDIR(old.st_mode):
        # A folder cannot be replaced atomically (nor by a file): move the old one aside first.
        aside = f".{target_name}.old-{os.getpid()}-{os.urandom(4).hex()}"
        os.rename(target_name, aside, src_dir_fd=target_fd, dst_dir_fd=target_fd)
    elif old is not None and source_is_folder:
        os.unlink(target_name, dir_fd=target_fd)  # a file or link where a folder goes
    os.replace(source_name, target_name, src_dir_fd=source_fd, dst_dir_fd=target_fd)
    if aside is not None:
        shutil.rmtree(aside, dir_fd=target_fd, ignore_errors=True)


def write_file(root: Path | str, relative: str, data: bytes) -> None:
    """Write `root/relative` whole by a temporary file and a rename (readers see the old or the new file);
    a folder or link at that name is replaced, never followed."""
    parent, _, name = relative.rpartition("/")
    temporary = f".{name}.tmp-{os.getpid()}"
    with folder(root, parent, create=True) as descriptor:
        with suppress(FileNotFoundError):
            os.unlink(temporary, dir_fd=descriptor)  # left by a process of the same pid that died
        handle = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644,
                         dir_fd=descriptor)
        with open(handle, "wb") as out:
            out.write(data)
        _replace_at(descriptor, temporary, descriptor, name)


def open_file(root: Path | str, relative: str, flags: int = os.O_RDONLY, mode: int = 0o644) -> int:
    """A descriptor of the file `root/relative` opened with `flags`, following no link (the file itself
    included: RunLinkError); folders are created when `flags` has O_CREAT."""
    parent, _, name = relative.rpartition("/")
    with folder(root, parent, create=bool(flags & os.O_CREAT)) as descriptor:
        try:
            return os.open(name, flags | os.O_NOFOLLOW | os.O_CLOEXEC, mode, dir_fd=descriptor)
        except OSError as error:
            if error.errno == errno.ELOOP:
                raise _refusal(root, relative) from None
            raise


def read_bytes(root: Path | str, relative: str, limit: int = -1) -> bytes:
    """The bytes of the file `root/relative` (the first `limit` ones when given), read without following a
    link (IsADirectoryError for a folder)."""
    with open(open_file(root, relative), "rb") as handle:
        # read(limit) would allocate `limit` bytes first: ask for them only when the file is that big.
        return handle.read(limit) if 0 <= limit <= os.fstat(handle.fileno()).st_size else handle.read()


def entries(root: Path | str, relative: str) -> list[tuple[str, bool]]:
    """(name, is a real folder) of the entries of the folder `root/relative`, reached without following a
    link; empty when it is missing (RunLinkError when a link stands in the way)."""
    try:
        with folder(root, relative) as descriptor, os.scandir(descriptor) as found:
            return [(entry.name, entry.is_dir(follow_symlinks=False)) for entry in found]
    except FileNotFoundError:
        return []


def is_link(path: str) -> bool:
    """True when `path` itself is a symbolic link (not followed)."""
    try:
        return stat.S_ISLNK(os.lstat(path).st_mode)
    except OSError:
        return False


def run_links(root: Path) -> list[str]:
    """Paths (relative to the run) of the links among the run's own folders: the root's entries and one
    level inside `_state`, `_staging`, `logs`, `videos` and the dataset index (a few directory listings)."""
    found = []
    for relative in ("", *OWN_FOLDERS):
        path = os.path.join(root, relative)
        if relative and is_link(path):
            continue  # reported as an entry of its parent
        try:
            with os.scandir(path) as entries:
                found.extend(f"{relative}/{e.name}".lstrip("/") for e in entries if e.is_symlink())
        except OSError:  # missing, not a folder, a loop: nothing to list
            continue
    return sorted(set(found))


class FolderCheck:
    """Folders of the run found to be real folders (no link on the way from the root) during one pass of
    checks: each folder is `lstat`ed once per pass, not once per file (a full-scale render marker names
    ~40 files in a few folders). Holds the first link found on the way to each bad folder."""

    def __init__(self, root: Path | str):
        self.prefix = os.path.join(os.fspath(root), "")
        self.real: set[str] = {""}
        self.bad: dict[str, str] = {}

    def problem(self, relative_folder: str) -> str | None:
        """None when `relative_folder` is reached through real folders only; else what stands in the way."""
        if relative_folder in self.real:
            return None
        if relative_folder in self.bad:
            return self.bad[relative_folder]
        parent, _, _ = relative_folder.rpartition("/")
        found = self.problem(parent)
        if found is None:
            try:
                mode = os.lstat(self.prefix + relative_folder).st_mode
            except FileNotFoundError:
                mode = None
            except OSError:  # a loop, a name too long: not a folder of the run
                mode = 0
            if mode is not None and stat.S_ISLNK(mode):
                found = f"passes through the symbolic link {relative_folder}"
            elif mode is None or not stat.S_ISDIR(mode):  # a file where a folder should be: the file is missing
                found = "is missing"
        if found is None:
            self.real.add(relative_folder)
        else:
            self.bad[relative_folder] = found
        return found
