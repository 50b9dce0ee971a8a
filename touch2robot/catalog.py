"""The DuckDB catalog: one database file (``<data>/catalog.duckdb``) holding a view per
lake table (over its Parquet files) and the SQL macros of ``touch2robot.sql``.

One writer, many readers: ``refresh`` takes the file read-write briefly (retrying while
another process holds the lock); ``query`` opens it read-only, sandboxed to the lake
folder, and accepts only SELECT/EXPLAIN statements."""

from __future__ import annotations

import random
import time
from pathlib import Path

import duckdb
import pyarrow as pa

from schemas.tables import PARTITIONS, SCHEMAS
from touch2robot import lake as lake_io
from touch2robot.settings import DataLayout

READ_ONLY_STATEMENTS = {duckdb.StatementType.SELECT, duckdb.StatementType.EXPLAIN}


class QueryRefused(ValueError):
    """A statement that the read-only SQL interface does not run."""


def _sql_type(t: pa.DataType) -> str:
    if pa.types.is_string(t):
        return "VARCHAR"
    if pa.types.is_float64(t):
        return "DOUBLE"
    if pa.types.is_float32(t):
        return "FLOAT"
    if pa.types.is_int64(t):
        return "BIGINT"
    if pa.types.is_int32(t):
        return "INTEGER"
    if pa.types.is_boolean(t):
        return "BOOLEAN"
    if pa.types.is_timestamp(t):
        return "TIMESTAMPTZ"
    if pa.types.is_fixed_size_list(t):
        return f"{_sql_type(t.value_type)}[{t.list_size}]"
    raise TypeError(f"no SQL type for {t}")


def _view_sql(lake: Path, name: str) -> str:
    schema = SCHEMAS[name]
    if not lake_io.files(lake, name):
        cols = ", ".join(f'CAST(NULL AS {_sql_type(f.type)}) AS "{f.name}"' for f in schema)
        return f"CREATE OR REPLACE VIEW {name} AS SELECT {cols} WHERE false"
    glob = (lake / name).as_posix() + "/**/*.parquet"
    hive = "true" if PARTITIONS.get(name) else "false"
    cols = ", ".join(f'"{f.name}"' for f in schema)  # contract column order, partition columns included
    return f"CREATE OR REPLACE VIEW {name} AS SELECT {cols} FROM read_parquet('{glob}', hive_partitioning = {hive}, union_by_name = true)"


def _connect_rw(path: Path, timeout_s: float = 60.0) -> duckdb.DuckDBPyConnection:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return duckdb.connect(str(path))
        except duckdb.IOException as e:
            if "lock" not in str(e).lower() or time.monotonic() > deadline:
                raise
            time.sleep(random.uniform(0.05, 0.3))  # another writer holds the file: wait our turn


def refresh(layout: DataLayout) -> list[str]:
    """(Re)create every table view and the SQL macros; returns the view names."""
    from touch2robot.metrics import register_contact_macros

    layout.root.mkdir(parents=True, exist_ok=True)
    con = _connect_rw(layout.catalog)
    try:
        for name in SCHEMAS:
            con.execute(_view_sql(layout.lake, name))
        register_contact_macros(con)
    finally:
        con.close()
    return list(SCHEMAS)


def connect_read_only(layout: DataLayout) -> duckdb.DuckDBPyConnection:
    """A read-only connection that can read the lake and nothing else on disk."""
    if not layout.catalog.exists():
        raise FileNotFoundError(
            f"no catalog at {layout.catalog}: run `touch2robot ingest` (or `touch2robot run`) first"
        )
    con = duckdb.connect(str(layout.catalog), read_only=True)
    if con.sql("SELECT current_setting('lock_configuration')").fetchall()[0][0]:
        # another connection of this process already sandboxed the shared database instance
        if con.sql("SELECT current_setting('enable_external_access')").fetchall()[0][0]:
            con.close()
            raise RuntimeError(f"{layout.catalog} is open in this process with external access enabled and locked")
        return con
    con.execute(f"SET allowed_directories = ['{layout.lake.as_posix()}/']")
    con.execute("SET enable_external_access = false")
    con.execute("SET lock_configuration = true")
    return con


def query(layout: DataLayout, sql: str) -> pa.Table:
    """Run read-only SQL against the catalog; refuses anything but SELECT/EXPLAIN."""
    statements = duckdb.extract_statements(sql)
    if not statements:
        raise QueryRefused("no SQL statement given")
    for st in statements:
        if st.type not in READ_ONLY_STATEMENTS:
            raise QueryRefused(f"refused: {st.type.name} statements are not allowed (read-only; SELECT/EXPLAIN only)")
    con = connect_read_only(layout)
    try:
        result = None
        for st in statements:
            result = con.sql(st.query).to_arrow_table()
        return result
    finally:
        con.close()
