"""Finding the recordings of a folder: every regular, readable ``*.mcap`` file below it and every rosbag2
folder (one holding a ``metadata.yaml``; its own files are its storage, not recordings of their own), and
for every other entry named like a recording (a directory, a FIFO, a device, a dangling or looping link, an
unreadable file) the reason it is skipped. Nothing here opens a file for reading, so a FIFO cannot block the
walk."""

from __future__ import annotations

import hashlib
import os
import stat
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

SUFFIX = ".mcap"
BAG_METADATA = "metadata.yaml"


def is_bag(path: Path) -> bool:
    """A rosbag2 recording: a folder with its ``metadata.yaml`` (stats only, nothing is opened)."""
    return os.path.isdir(path) and os.path.isfile(os.path.join(path, BAG_METADATA))


@dataclass(frozen=True)
class Scan:
    recordings: list[Path]  # sorted, absolute
    skipped: list[tuple[Path, str]]  # (entry, why it is not a recording)


_NOT_REGULAR = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def _kind(mode: int) -> str:
    return next((name for test, name in _NOT_REGULAR if test(mode)), "not a regular file")


def _walk_once(folder: Path, on_error: Callable[[OSError], None]) -> Iterator[tuple[str, os.stat_result, list, list]]:
    """``os.walk`` with links followed, each folder once (a folder reached twice, as by a link loop, is not walked
    again): (folder, its stat, its sub-folders, its files); emptying the sub-folders prunes them."""
    walked: set[tuple[int, int]] = set()
    for parent, dirs, files in os.walk(folder, onerror=on_error, followlinks=True):
        here = os.stat(parent)
        if (here.st_dev, here.st_ino) in walked:
            dirs.clear()
            continue
        walked.add((here.st_dev, here.st_ino))
        yield parent, here, dirs, files


def find_recordings(folder: Path) -> Scan:
    """The ``*.mcap`` recordings and rosbag2 folders below ``folder``, links followed (a folder reached twice,
    as by a link loop, is walked once). Raises FileNotFoundError/NotADirectoryError naming ``folder`` itself."""
    folder = Path(folder)
    if not folder.exists():
        raise FileNotFoundError(f"recordings folder {folder} does not exist")
    if not folder.is_dir():
        raise NotADirectoryError(f"recordings folder {folder} is not a directory")
    found, skipped = [], []

    def on_error(e: OSError) -> None:
        skipped.append((Path(e.filename or folder), f"cannot list: {e.strerror}"))

    for parent, _, dirs, files in _walk_once(folder, on_error):
        if is_bag(Path(parent)):  # the folder itself may be one
            if os.access(parent, os.R_OK | os.X_OK):
                found.append(Path(parent).absolute())
            else:
                skipped.append((Path(parent), "a rosbag2 folder that is not readable (permission denied)"))
            dirs.clear()
            continue
        dirs.sort()
        for name in sorted(n for n in dirs + files if n.endswith(SUFFIX)):
            entry = Path(parent) / name
            try:
                mode = entry.stat().st_mode  # follows links: a link to a file counts as that file
            except OSError as e:
                link = " (a dangling or looping link)" if entry.is_symlink() else ""
                skipped.append((entry, f"cannot stat{link}: {e.strerror}"))
                continue
            if is_bag(entry):
                continue  # a rosbag2 folder named like a file: the walk finds it
            if not stat.S_ISREG(mode):
                skipped.append((entry, f"{_kind(mode)}, not a recording file"))
            elif not os.access(entry, os.R_OK):
                skipped.append((entry, "not readable (permission denied)"))
            else:
                found.append(entry.absolute())
    return Scan(sorted(found), skipped)


def folder_state(folder: Path) -> str:
    """A digest of the state of every entry below ``folder``, walked as ``find_recordings`` walks it (links
    followed): each entry's path, type, inode, size, mtime and ctime, a link's own and its target's. A file
    written, added, removed or renamed there moves it, and an ingest is a function of its folder's files: two
    equal states need one ingest. A folder that cannot be walked has a new state every time."""
    folder = Path(folder)
    h = hashlib.sha256()
    unwalkable: list[OSError] = []
    walked = False
    try:
        for parent, here, dirs, files in _walk_once(folder, unwalkable.append):
            walked = True
            where = os.path.relpath(parent, folder)
            h.update(repr((where, here.st_mtime_ns, here.st_ctime_ns)).encode(errors="surrogateescape"))
            dirs.sort()
            for name in sorted(dirs + files):
                entry = os.path.join(parent, name)
                h.update(os.path.relpath(entry, folder).encode(errors="surrogateescape") + b"\0")
                for follow in (False, True):
                    try:
                        s = os.stat(entry, follow_symlinks=follow)
                    except OSError as e:
                        h.update(f"{type(e).__name__}\0".encode())
                        continue
                    h.update(repr((s.st_mode, s.st_dev, s.st_ino, s.st_size, s.st_mtime_ns, s.st_ctime_ns)).encode())
    except OSError as e:  # a folder gone while walked
        unwalkable.append(e)
    return uuid.uuid4().hex if unwalkable or not walked else h.hexdigest()
