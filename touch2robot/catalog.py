"""The DuckDB catalog: one database file (``<data>/catalog.duckdb``) holding a view per
lake table (over its Parquet files), with every table's and column's description from
``schemas.tables.DOCS`` as DuckDB comments, and the SQL macros of ``touch2robot.sql``.

One writer, many readers: ``refresh`` takes the file read-write briefly (retrying while
another process holds the lock). Readers (``connect_read_only``, ``query``) attach it
read-only just long enough to copy its definitions into a private in-memory database,
which is then sandboxed to reading the lake; ``query`` runs only SELECT statements (and
EXPLAIN of a SELECT), checked by DuckDB's parser before anything runs. DuckDB's
``allowed_directories`` grants writes as well as reads, so that statement allow-list is what
keeps the interface read-only; the sandbox keeps every other file, the catalog included, out
of reach."""

from __future__ import annotations

import hashlib
import random
import re
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import duckdb
import pyarrow as pa
import pyarrow.parquet as pq

from schemas.tables import DOCS, PARTITIONS, SCHEMAS
from touch2robot import lake as lake_io
from touch2robot.settings import DataLayout

DEFAULT_TIMEOUT_S = 60.0

# A scalar macro in the catalog naming the lake folder its views read: a reader of a copied or
# moved data folder sees it differ from its own lake and points the views at its own.
LAKE_FOLDER_MACRO = "lake_folder"
# A scalar macro holding the digest of the definitions (views, comments, macros) the catalog was refreshed with
DEFINITIONS_MACRO = "catalog_definitions"


class QueryRefused(ValueError):
    """A statement that the read-only SQL interface does not run."""


class QueryTimeout(TimeoutError):
    """A query interrupted because it ran past its time limit."""


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
    if pa.types.is_list(t):  # an array as wide as the rig's (glove taxels, TwinTac and FSR channels)
        return f"{_sql_type(t.value_type)}[]"
    raise TypeError(f"no SQL type for {t}")


def _sql_string(value: str) -> str:
    """``value`` as a SQL string literal, for the statements that take no parameters (DDL)."""
    if "\0" in value:
        raise ValueError(f"a NUL character cannot be part of a SQL string: {value!r}")
    return "'" + value.replace("'", "''") + "'"


def _glob_literal(path: Path) -> str:
    """``path`` as a glob pattern matching itself: DuckDB's glob metacharacters in folder
    names become one-character classes."""
    return re.sub(r"([*?\[])", r"[\1]", path.as_posix())


def _stored_columns(files: list[Path], wanted: set[str]) -> set[str]:
    """Which of ``wanted`` some file holds (footers only, newest first: usually the first has them all)."""
    found: set[str] = set()
    for path in sorted(files, key=lambda f: f.stat().st_mtime_ns, reverse=True):
        found |= wanted & set(pq.read_schema(path).names)
        if found == wanted:
            break
    return found


def _view_sql(lake: Path, name: str) -> str:
    schema = SCHEMAS[name]
    files = lake_io.files(lake, name)
    if not files:
        cols = ", ".join(f'CAST(NULL AS {_sql_type(f.type)}) AS "{f.name}"' for f in schema)
        return f"CREATE OR REPLACE VIEW {name} AS SELECT {cols} WHERE false"
    glob = _sql_string(_glob_literal(lake / name) + "/**/*.parquet")
    hive = "true" if PARTITIONS.get(name) else "false"
    partitions = set(PARTITIONS.get(name, ()))
    # a column no file holds yet (files written before the column existed) reads as NULL instead of
    # failing the whole catalog; union_by_name fills it where only some files lack it
    stored = _stored_columns(files, {f.name for f in schema} - partitions) | partitions
    cols = ", ".join(
        f'"{f.name}"' if f.name in stored else f'CAST(NULL AS {_sql_type(f.type)}) AS "{f.name}"' for f in schema
    )  # contract column order, partition columns included
    return (
        f"CREATE OR REPLACE VIEW {name} AS SELECT {cols} "
        f"FROM read_parquet({glob}, hive_partitioning = {hive}, union_by_name = true)"
    )


def _comments_sql(name: str) -> str:
    doc = DOCS[name]
    comments = [f"COMMENT ON VIEW {name} IS {_sql_string(doc.summary)}"]
    comments += [f'COMMENT ON COLUMN {name}."{col}" IS {_sql_string(text)}' for col, text in doc.columns.items()]
    return ";\n".join(comments)


def _view_statements(lake: Path) -> list[str]:
    """The statements of a commented view per table over ``lake``, and of the macro that records which lake."""
    statements = []
    for name in SCHEMAS:
        statements += [_view_sql(lake, name), _comments_sql(name)]
    statements.append(f"CREATE OR REPLACE MACRO {LAKE_FOLDER_MACRO}() AS {_sql_string(lake.as_posix())}")
    statements.append(f"COMMENT ON MACRO {LAKE_FOLDER_MACRO} IS 'the lake folder the views read'")
    return statements


def _create_views(con: duckdb.DuckDBPyConnection, lake: Path) -> None:
    for statement in _view_statements(lake):
        con.execute(statement)


def _retry_while_locked[T](action: Callable[[], T], timeout_s: float = 60.0) -> T:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return action()
        except duckdb.IOException as e:
            if "lock" not in str(e).lower() or time.monotonic() > deadline:
                raise
            time.sleep(random.uniform(0.05, 0.3))  # another writer holds the file: wait our turn


def _catalog_state(catalog: Path) -> tuple[lake_io.FileState, lake_io.FileState | None] | None:
    """The state of the catalog file and of its write-ahead log (a commit that was never checkpointed lives
    there), or None without a catalog."""
    try:
        state = lake_io.file_state(catalog)
    except OSError:
        return None
    try:
        return state, lake_io.file_state(catalog.with_name(catalog.name + ".wal"))
    except OSError:
        return state, None


# the definitions digest this process read back from a catalog (DuckDB writes in place: only its settled state is
# trusted); every flow refreshes, and opening the file to read it back costs 60-80 ms
_read_definitions: lake_io.StateMemo[tuple[lake_io.FileState, lake_io.FileState | None], str] = lake_io.StateMemo()


def _written_definitions(catalog: Path) -> str | None:
    """The digest of the definitions the catalog was last refreshed with (None: no catalog, none recorded, or
    the file is held by a writer)."""
    state = _catalog_state(catalog)  # before the reading: a write during it is a change of state
    if state is None:
        return None
    if (known := _read_definitions.get(catalog, state)) is not None:
        return known
    try:
        with duckdb.connect(str(catalog), read_only=True) as con:
            if not _scalar(con, "SELECT count(*) FROM duckdb_functions() WHERE function_name = ?", [DEFINITIONS_MACRO]):
                return None
            digest = _scalar(con, f"SELECT {DEFINITIONS_MACRO}()")
    except duckdb.Error:
        return None
    _read_definitions.put(catalog, state, digest, state)
    return digest


def refresh(layout: DataLayout) -> list[str]:
    """(Re)create every table view with its comments and the SQL macros; returns the view names.
    Refuses (LakeFileChanged, naming them) while lake files differ from what their stages wrote.
    A catalog that holds these definitions already is left as it is (every flow refreshes)."""
    from touch2robot.metrics import contact_macros_sql

    lake_io.check_all(layout.lake)
    statements = [*_view_statements(layout.lake), contact_macros_sql()]
    digest = hashlib.sha256("\0".join(statements).encode()).hexdigest()
    if _written_definitions(layout.catalog) == digest:
        return list(SCHEMAS)
    layout.root.mkdir(parents=True, exist_ok=True)
    con = _retry_while_locked(lambda: duckdb.connect(str(layout.catalog)))
    try:
        # one transaction: a reader sees all views old or all new, and one commit is faster than a
        # commit per statement (0.13 s against 0.19 s on the smoke lake, every flow refreshes)
        con.begin()
        for statement in statements:  # the contact macros last: DuckDB binds them to the views made before
            con.execute(statement)
        con.execute(f"CREATE OR REPLACE MACRO {DEFINITIONS_MACRO}() AS {_sql_string(digest)}")
        con.commit()
    finally:
        con.close()
    return list(SCHEMAS)


def _copy_catalog(con: duckdb.DuckDBPyConnection, catalog: Path) -> None:
    # the file is held only while copied; once detached it is no attached database, which
    # DuckDB would otherwise keep readable (as a file) inside the sandbox
    con.execute("ATTACH ? AS catalog_file (READ_ONLY)", [str(catalog)])  # raises while a writer holds it
    try:
        con.execute("COPY FROM DATABASE catalog_file TO memory")
    finally:
        con.execute("DETACH catalog_file")


def _scalar(con: duckdb.DuckDBPyConnection, sql: str, params: list | None = None) -> Any:
    return con.execute(sql, params or []).fetchall()[0][0]


def _recorded_lake(con: duckdb.DuckDBPyConnection) -> str | None:
    """The lake folder the catalog's views were written for (None before catalogs recorded it)."""
    if not _scalar(con, "SELECT count(*) FROM duckdb_functions() WHERE function_name = ?", [LAKE_FOLDER_MACRO]):
        return None
    return _scalar(con, f"SELECT {LAKE_FOLDER_MACRO}()")


def connect_read_only(layout: DataLayout) -> duckdb.DuckDBPyConnection:
    """A connection to a private in-memory copy of the catalog that can read the lake and no
    other file. Views point at this data folder's lake even if the catalog was written
    before the folder was copied or moved."""
    if not layout.catalog.exists():
        raise FileNotFoundError(
            f"no catalog at {layout.catalog}: run `touch2robot ingest` (or `touch2robot run`) first"
        )
    con = duckdb.connect(":memory:")  # a database instance of its own, so its sandbox is its own
    try:
        _retry_while_locked(lambda: _copy_catalog(con, layout.catalog))
        if _recorded_lake(con) != layout.lake.as_posix():
            _create_views(con, layout.lake)
        # DuckDB checks a glob against the allowed folders as spelled: the views' globs spell the
        # lake with its glob metacharacters escaped, which is a second spelling where it has any
        lake_spellings = {layout.lake.as_posix() + "/", _glob_literal(layout.lake) + "/"}
        con.execute("SET allowed_directories = ?", [sorted(lake_spellings)])
        # DuckDB allows its spill folder inside the sandbox; by default an in-memory database's
        # is `.tmp` in the working directory, shared: this one is the connection's own (created
        # only if a query spills, removed at close)
        spill = Path(tempfile.gettempdir()) / f"touch2robot-sql-{uuid.uuid4().hex}"
        con.execute("SET temp_directory = ?", [spill.as_posix()])
        con.execute("SET enable_external_access = false")
        con.execute("SET lock_configuration = true")
    except BaseException:
        con.close()
        raise
    return con


def _explained_statement(text: str) -> str:
    """The statement an EXPLAIN statement explains: what follows EXPLAIN, an optional ANALYZE
    and an optional parenthesised option list."""
    raw = text.encode()  # DuckDB's tokenizer gives byte offsets
    tokens = duckdb.tokenize(text)
    bounds = [
        (start, end, kind) for (start, kind), (end, _) in zip(tokens, [*tokens[1:], (len(raw), None)], strict=True)
    ]
    words = [
        (start, raw[start:end].decode().strip(), kind)
        for start, end, kind in bounds
        if kind != duckdb.token_type.comment
    ]
    i = 1  # past EXPLAIN
    if i < len(words) and words[i][1].upper() == "ANALYZE":
        i += 1
    if i < len(words) and words[i][1] == "(":
        depth = 0
        while i < len(words):
            _, word, kind = words[i]
            if kind == duckdb.token_type.operator:
                depth += word.count("(") - word.count(")")
            i += 1
            if depth == 0:
                break
    return raw[words[i][0] :].decode() if i < len(words) else ""


def _is_select(text: str) -> bool:
    try:
        statements = duckdb.extract_statements(text)
    except duckdb.Error:
        return False
    return len(statements) == 1 and statements[0].type == duckdb.StatementType.SELECT


def read_only_statements(sql: str) -> list[str]:
    """The statements of ``sql``, each a SELECT or an EXPLAIN (ANALYZE) of a SELECT, as DuckDB's
    parser reads them; ``QueryRefused`` names the first that is anything else."""
    statements = duckdb.extract_statements(sql)
    if not statements:
        raise QueryRefused("no SQL statement given")
    for st in statements:
        if st.type == duckdb.StatementType.SELECT:
            continue
        if st.type == duckdb.StatementType.EXPLAIN:
            if _is_select(_explained_statement(st.query)):
                continue
            raise QueryRefused("refused: EXPLAIN is allowed only of a SELECT (EXPLAIN ANALYZE runs its statement)")
        raise QueryRefused(f"refused: {st.type.name} statements are not allowed (read-only: SELECT and EXPLAIN only)")
    return [st.query for st in statements]


def query(layout: DataLayout, sql: str, timeout_s: float | None = DEFAULT_TIMEOUT_S) -> pa.Table:
    """Run read-only SQL against the catalog; the last statement's result. Refuses anything but
    SELECT and EXPLAIN of a SELECT; interrupts the query after ``timeout_s`` seconds (None or
    0: no limit)."""
    statements = read_only_statements(sql)
    con = connect_read_only(layout)
    timed_out = threading.Event()

    def interrupt() -> None:
        timed_out.set()
        con.interrupt()

    timer = threading.Timer(timeout_s, interrupt) if timeout_s else None
    try:
        if timer is not None:
            timer.start()
        result = None
        for statement in statements:
            result = con.sql(statement).to_arrow_table()
        return result
    except duckdb.InterruptException:
        if timed_out.is_set():
            raise QueryTimeout(f"query interrupted: it ran past its {timeout_s:g} s timeout") from None
        raise
    finally:
        if timer is not None:
            timer.cancel()
        con.close()


def _view_comment(con: duckdb.DuckDBPyConnection, name: str) -> str | None:
    return _scalar(con, "SELECT comment FROM duckdb_views() WHERE view_name = ?", [name])


def tables(layout: DataLayout) -> pa.Table:
    """Every table of the catalog: its name, row count and description."""
    con = connect_read_only(layout)
    try:
        rows = [
            {
                "table": name,
                "rows": _scalar(con, f'SELECT count(*) FROM "{name}"'),
                "description": _view_comment(con, name),
            }
            for name in SCHEMAS
        ]
    finally:
        con.close()
    return pa.Table.from_pylist(rows)


@dataclass(frozen=True)
class TableDescription:
    name: str
    summary: str | None  # None in a catalog written before tables had descriptions
    partition_keys: tuple[str, ...]
    columns: pa.Table  # column, type, description, partition_key


def describe(layout: DataLayout, name: str) -> TableDescription:
    """A table's description and its columns as the catalog holds them (DuckDB types, comments)."""
    if name not in SCHEMAS:
        raise ValueError(f"no table {name!r}; the tables are: {', '.join(SCHEMAS)}")
    keys = PARTITIONS.get(name, ())
    con = connect_read_only(layout)
    try:
        summary = _view_comment(con, name)
        columns = con.sql(
            "SELECT column_name AS column, data_type AS type, comment AS description "
            "FROM duckdb_columns() WHERE table_name = ? ORDER BY column_index",
            params=[name],
        ).to_arrow_table()
    finally:
        con.close()
    is_key = pa.array([column in keys for column in columns["column"].to_pylist()])
    return TableDescription(name, summary, keys, columns.append_column("partition_key", is_key))
