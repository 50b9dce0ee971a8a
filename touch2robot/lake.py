"""The Parquet lake: one folder per table under ``<data>/lake``, one file per recording
or rollout (named by its id), hive-style partition folders where ``schemas.tables.PARTITIONS``
says so. Every file is written to a temporary name and renamed into place, so a reader
or a crash never sees half a file, and re-writing the same id replaces it (idempotent).
Which id a file has, and who writes it, is the catalog's to say: ``touch2robot.datasets``."""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from schemas.tables import PARTITIONS, SCHEMAS


def write_atomic(table: pa.Table, path: Path) -> Path:
    """Write a Parquet file via a temporary sibling and an atomic rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        # dictionary-encode only strings: float sensor columns gain nothing from a dictionary
        # and cost a third of the write time. pyarrow.parquet is unannotated: the checker takes
        # the type of the default (True) for use_dictionary, which also takes a list of columns
        strings = [f.name for f in table.schema if pa.types.is_string(f.type)]
        pq.write_table(table, tmp, compression="zstd", compression_level=1, use_dictionary=strings)  # pyright: ignore[reportArgumentType]
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


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
        p.unlink()
        removed += 1
    return removed
