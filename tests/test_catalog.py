"""The DuckDB catalog: views over the lake, read-only SQL sandboxed to the lake."""

from __future__ import annotations

from pathlib import Path

import pytest

from touch2robot import catalog
from touch2robot import lake as lake_io
from touch2robot.config import load_profile
from touch2robot.contacts.extract import human_contacts
from touch2robot.ingest import ingest_file, recording_rows
from touch2robot.settings import DataLayout


@pytest.fixture(scope="module")
def layout(smoke_data: Path, tmp_path_factory: pytest.TempPathFactory) -> DataLayout:
    layout = DataLayout(tmp_path_factory.mktemp("catalog") / "data")
    for p in sorted((smoke_data / "recordings").glob("*_glove.mcap")):
        ingest_file(p, layout.lake)
    config = load_profile("smoke").contacts
    for rec in recording_rows(layout.lake).to_pylist():
        rows, _ = human_contacts(layout.lake, rec, config)
        lake_io.write_rows(layout.lake, "contacts", rec["recording_id"], rows, {"source": "human", "task": rec["task"]})
    catalog.refresh(layout)
    return layout


def test_views_and_the_readme_query(layout: DataLayout) -> None:
    result = catalog.query(
        layout, "SELECT region, avg(contact::INT) AS share FROM contacts GROUP BY ALL ORDER BY region"
    ).to_pylist()
    assert [r["region"] for r in result] == ["P1", "P2", "P3", "P4", "T1", "T2", "T3", "T4"]
    assert all(0 <= r["share"] <= 1 for r in result)
    tasks = catalog.query(layout, "SELECT DISTINCT task, source FROM contacts ORDER BY task").to_pylist()
    assert {r["task"] for r in tasks} == {"pick", "rotate", "wipe", "drawer"} and {r["source"] for r in tasks} == {
        "human"
    }
    # tables with no rows yet are typed empty views, so queries on them work
    assert catalog.query(layout, "SELECT count(*) AS n FROM twintac").to_pylist() == [{"n": 0}]


@pytest.mark.parametrize(
    "sql",
    [
        "CREATE TABLE x (a INT)",
        "INSERT INTO contacts VALUES (1)",
        "COPY (SELECT 1) TO '/tmp/touch2robot-evil.csv'",
        "ATTACH '/tmp/other.duckdb'",
        "SELECT 1; DROP VIEW contacts",
    ],
)
def test_writes_are_refused(layout: DataLayout, sql: str) -> None:
    with pytest.raises(catalog.QueryRefused):
        catalog.query(layout, sql)
    assert not Path("/tmp/touch2robot-evil.csv").exists()


def test_files_outside_the_lake_cannot_be_read(layout: DataLayout) -> None:
    import duckdb

    with pytest.raises(duckdb.PermissionException):
        catalog.query(layout, "SELECT * FROM read_csv('/etc/passwd')")
    with pytest.raises(duckdb.PermissionException):
        catalog.query(layout, f"SELECT * FROM read_parquet('{layout.root}/../*.parquet')")


def test_readers_coexist_with_each_other(layout: DataLayout) -> None:
    a = catalog.connect_read_only(layout)
    b = catalog.connect_read_only(layout)
    try:
        assert (
            a.sql("SELECT count(*) FROM recordings").fetchall() == b.sql("SELECT count(*) FROM recordings").fetchall()
        )
    finally:
        a.close()
        b.close()


def test_a_column_no_file_holds_yet_reads_as_null(tmp_path: Path) -> None:
    """A data folder written before a table gained a column (here comparison's ``variant``) still has a
    catalog: the column reads as NULL where no file holds it, its value where some do."""
    import pyarrow as pa

    from schemas.tables import SCHEMAS

    layout = DataLayout(tmp_path / "data")
    schema = SCHEMAS["comparison"]
    row = {f.name: None for f in schema} | {
        "reference_source": "human",
        "source": "real",
        "metric": "f1",
        "task": "*",
        "method": "touch2robot",
        "variant": "",
        "n_demonstrations": 4,
        "n_paired": 0,
        "confidence": 0.95,
        "n_resamples": 100,
        "seeds": "0",
        "seeds_missing": "",
    }
    old = pa.Table.from_pylist([row], schema=schema).drop_columns(["variant"])
    lake_io.write_atomic(old, lake_io.file_path(layout.lake, "comparison", "human__real"))
    catalog.refresh(layout)
    assert catalog.query(layout, "SELECT method, variant FROM comparison").to_pylist() == [
        {"method": "touch2robot", "variant": None}
    ]
    lake_io.write_rows(
        layout.lake, "comparison", "human__sim", pa.Table.from_pylist([row | {"source": "sim"}], schema=schema)
    )
    catalog.refresh(layout)
    assert catalog.query(layout, "SELECT source, variant FROM comparison ORDER BY source").to_pylist() == [
        {"source": "real", "variant": None},
        {"source": "sim", "variant": ""},
    ]


def test_a_refresh_with_unchanged_definitions_leaves_the_catalog_as_it_is(tmp_path: Path) -> None:
    """Every flow refreshes the catalog; one whose views, comments and macros would come out the same is not
    rewritten, and a lake that changes what a view must say (a table's first file) is."""
    import pyarrow as pa

    from schemas.tables import SCHEMAS

    layout = DataLayout(tmp_path / "data")
    catalog.refresh(layout)
    written = layout.catalog.stat().st_mtime_ns
    catalog.refresh(layout)
    assert layout.catalog.stat().st_mtime_ns == written
    assert catalog.query(layout, "SELECT count(*) AS n FROM user_study").to_pylist() == [{"n": 0}]

    row = {f.name: None for f in SCHEMAS["user_study"]} | {
        "ratings_file": "r.csv",
        "ratings_sha256": "0" * 64,
        "question": "Q1",
        "n": 8,
        "n_zero": 0,
        "zero_method": "wilcox",
        "method": "wilcoxon",
        "correction": True,
        "synthetic": True,
    }
    table = pa.Table.from_pylist([row], schema=SCHEMAS["user_study"])
    lake_io.write_rows(layout.lake, "user_study", "r", table)
    catalog.refresh(layout)
    assert layout.catalog.stat().st_mtime_ns != written
    assert catalog.query(layout, "SELECT question FROM user_study").to_pylist() == [{"question": "Q1"}]


def test_a_catalog_rewritten_behind_a_refresh_is_refreshed_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A refresh remembers the definitions it read back from the catalog by the file's state; a catalog written
    since (another command's refresh, by hand) has another state and is read, and refreshed, again."""
    import time

    import duckdb

    monkeypatch.setattr(lake_io, "SETTLED_NS", 0)  # a catalog of this test is seconds old at most
    layout = DataLayout(tmp_path / "data")
    catalog.refresh(layout)
    written = catalog._written_definitions(layout.catalog)
    assert written is not None and catalog._written_definitions(layout.catalog) == written

    time.sleep(0.05)  # past the timestamp tick of the refresh's write
    with duckdb.connect(str(layout.catalog)) as con:
        con.execute(f"CREATE OR REPLACE MACRO {catalog.DEFINITIONS_MACRO}() AS 'tampered'")
        con.execute("DROP VIEW user_study")
    assert catalog._written_definitions(layout.catalog) == "tampered"
    catalog.refresh(layout)
    assert catalog._written_definitions(layout.catalog) == written
    assert catalog.query(layout, "SELECT count(*) AS n FROM user_study").to_pylist() == [{"n": 0}]
