"""The Parquet lake: one folder per table under ``<data>/lake``, one file per recording
or rollout (named by its id), hive-style partition folders where ``schemas.tables.PARTITIONS``
says so. Every file is written to a temporary name and renamed into place, so a reader
or a crash never sees half a file, and re-writing the same id replaces it (idempotent).
Beside every file lies its producer's digest (``.<id>.parquet.sha256``, written after the file):
a file changed by anything but this module (a stray ``COPY ... TO``, a disk fault, a half-finished
copy) no longer matches it, and ingest and the catalog refresh find it with ``check``.
Which id a file has, and who writes it, is the catalog's to say: ``touch2robot.datasets``."""

from __future__ import annotations

import hashlib
import os
import stat
import time
import uuid
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from schemas.tables import PARTITIONS, SCHEMAS

DIGEST_SUFFIX = ".sha256"


class LakeFileChanged(RuntimeError):
    """Lake files that no longer match the digest their producer wrote."""


def digest_path(path: Path) -> Path:
    # hidden: readers of a table's folder (pyarrow datasets, DuckDB globs) skip dot files
    return path.with_name(f".{path.name}{DIGEST_SUFFIX}")


def _sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def replace_text(text: str, path: Path) -> None:
    """Write a text file whole: a temporary sibling renamed over it (a reader never sees half of it)."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_atomic(table: pa.Table, path: Path) -> Path:
    """Write a Parquet file via a temporary sibling and an atomic rename, then its digest. A crash
    between the two renames leaves a file whose digest does not match: ``check`` reports it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        # dictionary-encode only strings: float sensor columns gain nothing from a dictionary
        # and cost a third of the write time. pyarrow.parquet is unannotated: the checker takes
        # the type of the default (True) for use_dictionary, which also takes a list of columns
        strings = [f.name for f in table.schema if pa.types.is_string(f.type)]
        pq.write_table(table, tmp, compression="zstd", compression_level=1, use_dictionary=strings)  # pyright: ignore[reportArgumentType]
        digest = _sha256(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    replace_text(digest, digest_path(path))
    return path


type FileState = tuple[int, int, int, int]


def file_state(path: Path) -> FileState:
    """What changes whenever a regular file's content does (OSError for anything else): a write changes its
    ctime, which no user call can set back, and a rename-over its inode."""
    s = path.stat()
    if not stat.S_ISREG(s.st_mode):
        raise IsADirectoryError(f"{path} is no regular file")
    return (s.st_ino, s.st_size, s.st_mtime_ns, s.st_ctime_ns)


# File timestamps advance by the kernel's tick (milliseconds): a file rewritten in place, at its size, in the tick
# it was last written in keeps its state. A state older than this cannot come back, so only such a state is
# trusted to mean the content that was read with it.
SETTLED_NS = 2_000_000_000


def settled(state: FileState) -> bool:
    """Whether a later write of the file is bound to move ``state`` (see SETTLED_NS)."""
    return time.time_ns() - state[3] > SETTLED_NS


class StateMemo[K, V]:
    """What this process derived from a file (its hash checked, its rows, a catalog's definitions), kept with the
    key it was derived under (the file's states, its digest) and given back while that key stays: a cached run
    checks and reads the same lake files at every flow. Only a key of settled states is kept."""

    def __init__(self) -> None:
        self._values: dict[Path, tuple[K, V]] = {}

    def get(self, path: Path, key: K) -> V | None:
        known = self._values.get(path)
        return known[1] if known is not None and known[0] == key else None

    def put(self, path: Path, key: K, value: V, states: tuple[FileState | None, ...]) -> None:
        if all(state is None or settled(state) for state in states):
            self._values[path] = (key, value)


# a cached smoke run's flows check its 300-file lake eight times over (50 ms each)
_verified: StateMemo[tuple[FileState, str], bool] = StateMemo()
# Arrow tables are immutable: one read serves every later reader of an unchanged file
_rows: StateMemo[tuple[FileState, str, pa.Schema], pa.Table] = StateMemo()


def check(path: Path) -> str | None:
    """Why ``path`` cannot be trusted (missing, no digest, changed since written), or None."""
    try:
        state = file_state(path)  # before the hashing: a change during it is a change of state
    except OSError:
        return "missing"
    try:
        written = digest_path(path).read_text().strip()
    except OSError:
        return "no producer digest beside it (not written by a touch2robot stage)"
    if _verified.get(path, (state, written)):
        return None
    if _sha256(path) != written:
        return "changed since its stage wrote it"
    _verified.put(path, (state, written), True, (state,))
    return None


def read_rows(path: Path, schema: pa.Schema) -> pa.Table:
    """A lake file's rows (as ``schema``), read again only when its state or producer digest moved since this
    process last read it (a file without a digest is read every time). It checks no digest: ``check`` does."""
    try:
        state = file_state(path)
        key = (state, digest_path(path).read_text().strip(), schema)
    except OSError:
        return pq.read_table(path, schema=schema)
    if (table := _rows.get(path, key)) is not None:
        return table
    table = pq.read_table(path, schema=schema)
    _rows.put(path, key, table, (state,))
    return table


def check_all(lake: Path) -> None:
    """Raise LakeFileChanged naming every lake file that does not match its producer's digest."""
    bad = []
    for path in sorted(lake.rglob("*.parquet")):
        why = None if path.name.startswith(".") else check(path)
        if why:
            bad.append(f"{path.relative_to(lake)}: {why}")
    if bad:
        raise LakeFileChanged(
            f"{len(bad)} lake file(s) in {lake} changed outside their stage; re-run the stage that writes them "
            f"(`touch2robot ingest` re-ingests recordings) or delete them: " + "; ".join(bad[:10])
        )


def remove(path: Path) -> None:
    """Delete a lake file and its digest."""
    path.unlink(missing_ok=True)
    digest_path(path).unlink(missing_ok=True)


def file_path(lake: Path, table: str, file_id: str, partition: dict[str, str] | None = None) -> Path:
    """Where the rows of one recording/rollout of a table live."""
    expected = PARTITIONS.get(table, ())
    partition = partition or {}
    if tuple(partition) != expected:
        raise ValueError(f"table {table!r} is partitioned by {expected}, got {tuple(partition)}")
    folder = lake / table
    for key in expected:
        value = str(partition[key])
        if not value or "/" in value or value.startswith("."):
            raise ValueError(f"bad partition value {key}={value!r} for table {table!r}")
        folder = folder / f"{key}={value}"
    return folder / f"{file_id}.parquet"


def write_rows(lake: Path, table: str, file_id: str, rows: pa.Table, partition: dict[str, str] | None = None) -> Path:
    """Validate rows against the table's schema and write them as one file. Partition
    columns are dropped from the file (the folder names carry them)."""
    schema = SCHEMAS[table]
    if "seed" in schema.names and schema.field("seed").nullable and "seed" not in rows.column_names:
        rows = rows.append_column("seed", pa.nulls(len(rows), pa.int64()))  # rows no sweep seed made (the glove's)
    try:
        rows = rows.select(schema.names).cast(schema)
    except (KeyError, pa.ArrowInvalid, pa.ArrowTypeError) as e:
        raise ValueError(f"rows for table {table!r} do not match its schema: {e}") from None
    keys = PARTITIONS.get(table, ())
    if keys:
        rows = rows.drop_columns(list(keys))
    return write_atomic(rows, file_path(lake, table, file_id, partition))


def files(lake: Path, table: str) -> list[Path]:
    return sorted(p for p in (lake / table).rglob("*.parquet") if not p.name.startswith("."))


def remove_id(lake: Path, file_id: str) -> int:
    """Delete every file of one recording/rollout id across all tables; returns the count."""
    removed = 0
    for p in lake.rglob(f"{file_id}.parquet"):
        remove(p)
        removed += 1
    return removed
