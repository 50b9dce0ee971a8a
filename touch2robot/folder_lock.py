"""One writing run per data folder. Two runs on one folder would resume from each other's half-written
checkpoints and cache each other's partial results; so a command that writes takes the folder's lock, and
a second one refuses at once, naming the holder. The lock is the kernel's (flock): it goes with the
holding process, so a run killed with SIGKILL leaves no stale lock behind."""

from __future__ import annotations

import fcntl
import json
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

LOCK_NAME = ".run.lock"


class DataFolderBusy(RuntimeError):
    """Another process holds the data folder's lock."""


@contextmanager
def hold_data_folder(root: Path, command: str) -> Iterator[None]:
    """Hold ``root``'s writer lock while the block runs, or raise DataFolderBusy naming the holder."""
    root.mkdir(parents=True, exist_ok=True)
    path = root / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise DataFolderBusy(
                f"{root} is in use by {_holder(path)}: wait for it to end, or use another --data"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "command": command, "since": time.time()}).encode())
        try:
            yield
        finally:
            os.ftruncate(fd, 0)
    finally:
        os.close(fd)  # releases the lock


def _holder(path: Path) -> str:
    try:
        info = json.loads(path.read_text() or "{}")
    except (OSError, ValueError):
        info = {}
    if "pid" not in info:
        return "another process"
    since = time.strftime("%H:%M:%S", time.localtime(info.get("since", 0)))
    return f"pid {info['pid']} ({info.get('command', '?')}, since {since})"
