"""The SQL interface on tiny lakes: read-only by construction (parser allow-list, sandbox to
the lake, configuration never interpolated), portable data folders, the query timeout, the
column descriptions, and what `touch2robot sql` prints."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import duckdb
import pyarrow as pa
import pytest
from typer.testing import CliRunner

from app.cli import app
from schemas.tables import DOCS, PARTITIONS, SCHEMAS
from touch2robot import catalog
from touch2robot import lake as lake_io
from touch2robot.settings import DataLayout


def _contacts(source: str, method: str, sequence_id: str, contact: list[bool]) -> pa.Table:
    n = len(contact)
    return pa.table(
        {
            "source": [source] * n,
            "method": [method] * n,
            "task": ["pick"] * n,
            "subject": ["s01"] * n,
            "sequence_id": [sequence_id] * n,
            "reference_id": ["h1"] * n,
            "t": [0.1 * i for i in range(n)],
            "t_ref": [0.1 * i for i in range(n)],
            "region": ["T1"] * n,
            "contact": contact,
            "value": [None] + [0.5] * (n - 1),
        }
    )


def _tiny_data(root: Path) -> DataLayout:
    """A data folder with a few rows of time_map and contacts (human and sim), catalog refreshed."""
    layout = DataLayout(root)
    time_map = pa.table({"recording_id": ["r1", "r1"], "t": [0.1234567891, 2.0], "t_ref": [0.0, 1.0]})
    lake_io.write_rows(layout.lake, "time_map", "r1", time_map)
    for source, method, sequence_id, contact in (
        ("human", "human", "h1", [False, True, True, False]),
        ("sim", "touch2robot", "sim-1", [False, False, True, True]),
    ):
        rows = _contacts(source, method, sequence_id, contact)
        lake_io.write_rows(layout.lake, "contacts", sequence_id, rows, {"source": source, "task": "pick"})
    catalog.refresh(layout)
    return layout


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> DataLayout:
    """Shared and never changed: tests that change a data folder make their own."""
    return _tiny_data(tmp_path_factory.mktemp("sql") / "data")


def _lake_state(layout: DataLayout) -> dict[Path, tuple[int, int]]:
    return {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in layout.lake.rglob("*") if p.is_file()}


def _sql_string(value: str) -> str:
    return "'" + value.replace("'", "''") + "'"


# --- descriptions ---------------------------------------------------------------------


def test_every_table_and_column_has_a_description() -> None:
    assert list(DOCS) == list(SCHEMAS)
    for name, schema in SCHEMAS.items():
        doc = DOCS[name]
        assert doc.summary.strip() and "\n" not in doc.summary, name
        assert list(doc.columns) == schema.names, f"{name}: descriptions do not follow the schema's columns"
        assert all(text.strip() for text in doc.columns.values()), name


def test_any_duckdb_client_sees_the_descriptions(tiny: DataLayout) -> None:
    con = duckdb.connect(str(tiny.catalog), read_only=True)
    try:
        views = dict(con.execute("SELECT view_name, comment FROM duckdb_views() WHERE NOT internal").fetchall())
        columns = {
            (table, column): comment
            for table, column, comment in con.execute(
                "SELECT table_name, column_name, comment FROM duckdb_columns()"
            ).fetchall()
        }
    finally:
        con.close()
    for name, doc in DOCS.items():
        assert views[name] == doc.summary
        for column, text in doc.columns.items():
            assert columns[(name, column)] == text


# --- read-only by construction ----------------------------------------------------------


@pytest.mark.parametrize(
    "probe",
    [
        "EXPLAIN ANALYZE COPY (SELECT * FROM time_map) TO '{lake}/recordings/x.parquet'",
        "EXPLAIN ANALYZE COPY (SELECT * FROM contacts) TO '{lake}/contacts/source=human/task=pick/h1.parquet'",
        "EXPLAIN (ANALYZE, FORMAT json) COPY (SELECT 1) TO '{lake}/x.parquet'",
        "EXPLAIN /* a */ ANALYZE COPY (SELECT 1) TO '{lake}/x.parquet'",
        "SELECT 1; COPY (SELECT 1) TO '{lake}/x.parquet'",
        "EXPLAIN ANALYZE CREATE TABLE x AS SELECT 1",
        "EXPLAIN ANALYZE INSERT INTO time_map VALUES ('r9', 0, 0)",
        "EXPORT DATABASE '{lake}/export'",
        "CALL pragma_version()",
        "SET threads = 1",
    ],
)
def test_statements_that_could_write_are_refused_and_the_lake_is_untouched(tiny: DataLayout, probe: str) -> None:
    before = _lake_state(tiny)
    with pytest.raises(catalog.QueryRefused):
        catalog.query(tiny, probe.format(lake=tiny.lake.as_posix()))
    assert _lake_state(tiny) == before


def test_explain_of_a_select_runs(tiny: DataLayout) -> None:
    plan = catalog.query(tiny, "EXPLAIN ANALYZE SELECT count(*) FROM contacts")
    assert plan.num_rows == 1
    assert catalog.query(tiny, "EXPLAIN SELECT * FROM time_map").num_rows == 1
    assert catalog.query(tiny, "SUMMARIZE time_map").num_rows == 3


def test_the_catalog_file_cannot_be_read(tiny: DataLayout) -> None:
    for path in (tiny.catalog.as_posix(), f"{tiny.lake.as_posix()}/../catalog.duckdb"):
        with pytest.raises(duckdb.PermissionException):
            catalog.query(tiny, f"SELECT size FROM read_blob({_sql_string(path)})")
    con = catalog.connect_read_only(tiny)
    try:
        # the configuration is locked: the sandbox cannot be widened from inside
        with pytest.raises(duckdb.Error):
            con.execute("SET allowed_directories = ['/']")
    finally:
        con.close()


@pytest.mark.parametrize("folder", ["it's", "x', '/', '", "w[1]*"])
def test_odd_data_folders_work_and_widen_nothing(tmp_path: Path, folder: str) -> None:
    layout = _tiny_data(tmp_path / folder / "data")
    assert catalog.query(layout, "SELECT count(*) AS n FROM time_map").to_pylist() == [{"n": 2}]
    for outside in ("/etc/hostname", f"{tmp_path.as_posix()}/{folder}/data/catalog.duckdb"):
        with pytest.raises(duckdb.PermissionException):
            catalog.query(layout, f"SELECT * FROM read_text({_sql_string(outside)})")
    allowed = catalog.query(layout, "SELECT unnest(current_setting('allowed_directories')) AS d")["d"].to_pylist()
    lake = [d for d in allowed if d.startswith(f"{tmp_path.as_posix()}/") and d.endswith("/data/lake/")]
    spill = [d for d in allowed if Path(d).name.startswith("touch2robot-sql-")]  # DuckDB's own, one per connection
    assert lake and len(spill) == 1 and sorted(lake + spill) == sorted(allowed)


# --- portability and the timeout --------------------------------------------------------


def test_a_moved_data_folder_still_answers(tmp_path: Path) -> None:
    old = _tiny_data(tmp_path / "old" / "data")
    moved = DataLayout(tmp_path / "new" / "data")
    shutil.move(old.root, moved.root)
    assert catalog.query(moved, "SELECT count(*) AS n FROM time_map").to_pylist() == [{"n": 2}]
    assert catalog.query(moved, "SELECT lake_folder() AS f")["f"].to_pylist() == [moved.lake.as_posix()]
    # the contact macros follow the views to the new lake
    counts = catalog.query(moved, "SELECT tp, fp, fn, tn FROM contact_counts('human', 'sim')").to_pylist()
    assert counts == [{"tp": 1, "fp": 1, "fn": 1, "tn": 1}]
    assert catalog.describe(moved, "contacts").summary == DOCS["contacts"].summary
    # a refresh writes the new place into the file itself
    catalog.refresh(moved)
    con = duckdb.connect(str(moved.catalog), read_only=True)
    try:
        assert con.execute("SELECT count(*) FROM time_map").fetchall() == [(2,)]
    finally:
        con.close()


def test_the_timeout_interrupts_a_runaway_query(tiny: DataLayout) -> None:
    started = time.monotonic()
    with pytest.raises(catalog.QueryTimeout, match="1 s timeout"):
        catalog.query(tiny, "SELECT count(*) FROM range(1000000000) a, range(1000000000) b", timeout_s=1)
    assert time.monotonic() - started < 30
    assert catalog.query(tiny, "SELECT 1 AS one", timeout_s=1).to_pylist() == [{"one": 1}]


# --- the command ------------------------------------------------------------------------


def _sql(*args: str, columns: int = 80) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["sql", *args], env={"COLUMNS": str(columns)})
    return result.exit_code, result.output


def test_rounded_floats_and_null(tiny: DataLayout) -> None:
    code, out = _sql("-d", str(tiny.root), "SELECT t, 1/3 AS third, NULL AS nothing FROM time_map ORDER BY t")
    assert code == 0, out
    assert "0.123457" in out and "0.333333" in out and "NULL" in out
    assert "None" not in out and "0.1234567891" not in out and "-[ RECORD" not in out
    code, out = _sql("-d", str(tiny.root), "--csv", "SELECT t, 1/3 AS third FROM time_map ORDER BY t")
    assert code == 0 and "0.1234567891,0.3333333333333333" in out, out


def test_wide_rows_are_shown_one_field_per_line(tiny: DataLayout) -> None:
    wide = "SELECT recording_id, repeat('x', 100) AS wide FROM time_map ORDER BY t"
    code, out = _sql("-d", str(tiny.root), wide)
    assert code == 0, out
    assert "-[ RECORD 1 ]" in out and "-[ RECORD 2 ]" in out and "…" not in out
    assert "x" * 40 in out
    code, out = _sql("-d", str(tiny.root), "--vertical", "SELECT 1 AS a")
    assert code == 0 and "-[ RECORD 1 ]" in out, out
    code, out = _sql("-d", str(tiny.root), wide, columns=200)
    assert code == 0 and "-[ RECORD" not in out, out


def test_tables_describe_and_help(tiny: DataLayout) -> None:
    code, out = _sql("-d", str(tiny.root), "--tables", columns=200)
    assert code == 0, out
    lines = {line.split()[1]: line for line in out.splitlines() if line.startswith("│")}
    assert list(lines) == list(SCHEMAS)
    assert " 2 " in lines["time_map"] and DOCS["time_map"].summary in lines["time_map"]
    assert " 8 " in lines["contacts"] and " 0 " in lines["rollouts"]

    code, out = _sql("-d", str(tiny.root), "--describe", "contacts", columns=200)
    assert code == 0, out
    assert DOCS["contacts"].summary in out and f"partitioned by {', '.join(PARTITIONS['contacts'])}" in out
    for column, text in DOCS["contacts"].columns.items():
        assert column in out and text in out
    assert "BOOLEAN" in out and "(partition key)" in out

    code, out = _sql("-d", str(tiny.root), "--describe", "nope")
    assert code == 1 and "no table 'nope'" in out

    code, out = _sql("--help", columns=300)
    assert code == 0
    assert all(name in out for name in SCHEMAS)


def test_the_command_refuses_writes(tiny: DataLayout) -> None:
    before = _lake_state(tiny)
    probe = f"EXPLAIN ANALYZE COPY (SELECT 1) TO '{tiny.lake.as_posix()}/recordings/x.parquet'"
    code, out = _sql("-d", str(tiny.root), probe)
    assert code == 1 and "QueryRefused" in out
    assert _lake_state(tiny) == before
    code, out = _sql("-d", str(tiny.root))
    assert code == 2
