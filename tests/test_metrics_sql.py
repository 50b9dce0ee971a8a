"""The DuckDB contact macros agree exactly with the Python metrics over a hive-partitioned lake."""

from __future__ import annotations

from pathlib import Path

import duckdb
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from schemas.tables import PARTITIONS, ROBOT_REGIONS
from schemas.tables import contacts as CONTACTS_SCHEMA
from touch2robot.metrics import (
    ALL,
    CONTACT_KEYS,
    COUNT_COLUMNS,
    align_to_reference,
    contact_counts_long,
    contact_scores,
    contact_scores_table,
    register_contact_macros,
)

TASKS = ("pick", "wipe")
SUBJECTS = ("s1", "s2", "s3")
EVAL = {"sim": ("m_a", "m_b"), "real": ("m_a",), "reconstructed": ("m_c",)}


def _human(rng: np.random.Generator, seq: str, task: str, subject: str) -> pd.DataFrame:
    # Uneven sampling; P4 is never in contact (0/0 precision/recall/F1), P1 always is (0/0 FPR).
    t = np.cumsum(rng.uniform(0.01, 0.05, size=rng.integers(30, 60)))
    frames = []
    for region in ROBOT_REGIONS:
        contact = rng.random(t.size) < 0.4
        if region == "P4":
            contact[:] = False
        if region == "P1":
            contact[:] = True
        frames.append(pd.DataFrame({"t": t, "t_ref": t, "region": region, "contact": contact}))
    return pd.concat(frames).assign(
        source="human", method="human", task=task, subject=subject, sequence_id=seq, reference_id=seq
    )


def _evaluated(
    rng: np.random.Generator,
    source: str,
    method: str,
    seq: str,
    ref: pd.DataFrame | None,
    ref_id: str,
    task: str,
    subject: str,
) -> pd.DataFrame:
    ref_t = np.unique(ref["t_ref"]) if ref is not None else np.array([0.0, 1.0])
    # Non-uniform, partly unsorted t_ref: some before the first reference sample (dropped),
    # some exactly on reference samples (the `>=` edge), some past the end.
    n = int(rng.integers(20, 50))
    t_ref = np.concatenate(
        [
            rng.uniform(ref_t[0] - 0.2, ref_t[-1] + 0.2, size=n),
            rng.choice(ref_t, size=5),
            [ref_t[0] - 1e-9],
        ]
    )
    rng.shuffle(t_ref)
    frames = []
    for region in ROBOT_REGIONS:
        contact = rng.random(t_ref.size) < (0.0 if region == "P4" else 0.5)
        frames.append(
            pd.DataFrame(
                {
                    "t": np.arange(t_ref.size) * 0.02,
                    "t_ref": t_ref,
                    "region": region,
                    "contact": contact,
                }
            )
        )
    return pd.concat(frames).assign(
        source=source, method=method, task=task, subject=subject, sequence_id=seq, reference_id=ref_id
    )


def _generate(seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    frames = []
    for task in TASKS:
        for subject in SUBJECTS:
            for rep in range(2):
                hid = f"h_{task}_{subject}_{rep}"
                human = _human(rng, hid, task, subject)
                frames.append(human)
                for source, methods in EVAL.items():
                    for method in methods:
                        frames.append(
                            _evaluated(rng, source, method, f"{source}_{method}_{hid}", human, hid, task, subject)
                        )
    # An evaluated sequence whose reference is not in the lake: all of its samples drop.
    frames.append(_evaluated(rng, "sim", "m_a", "sim_orphan", None, "h_missing", "pick", "s1"))
    df = pd.concat(frames, ignore_index=True)
    df["value"] = rng.random(len(df)).astype(np.float32)
    df["seed"] = np.where(df["source"] == "human", np.nan, 0)  # the glove's rows have no sweep seed
    return df[CONTACTS_SCHEMA.names]


def _write_lake(df: pd.DataFrame, root: Path) -> None:
    parts = PARTITIONS["contacts"]
    file_schema = pa.schema([f for f in CONTACTS_SCHEMA if f.name not in parts])
    for (source, task, seq), g in df.groupby(["source", "task", "sequence_id"]):
        d = root / "contacts" / f"source={source}" / f"task={task}"
        d.mkdir(parents=True, exist_ok=True)
        table = pa.Table.from_pandas(g[file_schema.names], schema=file_schema, preserve_index=False)
        pq.write_table(table, d / f"{seq}.parquet")


@pytest.fixture(params=[0, 1], scope="module")
def lake(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    df = _generate(request.param)
    root = tmp_path_factory.mktemp(f"lake{request.param}")
    _write_lake(df, root)
    con = duckdb.connect()
    glob = (root / "contacts" / "**" / "*.parquet").as_posix().replace("'", "''")
    con.execute(f"CREATE VIEW contacts AS SELECT * FROM read_parquet('{glob}', hive_partitioning = true)")
    register_contact_macros(con)
    # Python reads the same lake back, so both sides see identical values.
    lake_df = con.sql("SELECT * FROM contacts").df()
    yield con, lake_df
    con.close()


def _sorted(df: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    return df.sort_values(keys, kind="stable").reset_index(drop=True)


@pytest.mark.parametrize("eval_source", sorted(EVAL))
def test_counts_sql_equals_python(lake, eval_source: str) -> None:
    con, df = lake
    sql = con.sql(f"SELECT * FROM contact_counts('human', '{eval_source}')").df()
    py = contact_counts_long(df, ref_source="human", eval_source=eval_source)
    keys = list(CONTACT_KEYS)
    assert not py.empty
    pd.testing.assert_frame_equal(_sorted(sql, keys), _sorted(py, keys), check_exact=True)


@pytest.mark.parametrize("eval_source", ["sim", "real"])
@pytest.mark.parametrize(
    "by",
    [
        ("method",),
        ("method", "task"),
        ("method", "region"),
        ("method", "subject"),
        ("method", "task", "subject"),
        ("method", "task", "subject", "region"),
    ],
)
def test_score_slices_sql_equals_python(lake, eval_source: str, by: tuple[str, ...]) -> None:
    con, df = lake
    rolled = [d for d in ("task", "subject", "region") if d not in by]
    kept = [d for d in ("task", "subject", "region") if d in by]
    where = " AND ".join([f"{d} = '{ALL}'" for d in rolled] + [f"{d} <> '{ALL}'" for d in kept])
    sql = con.sql(
        f"SELECT * EXCLUDE ({', '.join(rolled)}) FROM contact_score_slices('human', '{eval_source}') WHERE {where}"
        if rolled
        else f"SELECT * FROM contact_score_slices('human', '{eval_source}') WHERE {where}"
    ).df()
    py = contact_scores_table(contact_counts_long(df, eval_source=eval_source), by=by)
    sql = _sorted(sql[list(py.columns)], list(by))
    py = _sorted(py, list(by))
    pd.testing.assert_frame_equal(sql, py, check_exact=True)
    if "region" in by:
        p4 = py[py["region"] == "P4"]
        assert p4["precision"].isna().all() and p4["recall"].isna().all() and p4["f1"].isna().all()
        assert py.loc[py["region"] == "P1", "fpr"].isna().all()


def test_sql_pairs_follow_align_to_reference_and_array_scores(lake) -> None:
    con, df = lake
    seq = "real_m_a_h_wipe_s2_1"
    ev = df[df["sequence_id"] == seq]
    ref = df[(df["source"] == "human") & (df["sequence_id"] == ev["reference_id"].iloc[0])]
    aligned_cols, eval_cols = [], []
    for region in ROBOT_REGIONS:
        r = ref[ref["region"] == region].sort_values("t_ref")
        e = ev[ev["region"] == region].sort_values("t")
        aligned, kept = align_to_reference(r["t_ref"], r["contact"].to_numpy(), e["t_ref"])
        aligned_cols.append(aligned)
        eval_cols.append(e["contact"].to_numpy()[kept])
    # Every region of the sequence shares its t_ref, so the kept samples form a (time, region) grid.
    py = contact_scores(np.column_stack(aligned_cols), np.column_stack(eval_cols), per_region=True)
    sql = (
        con.sql(
            "SELECT region, count_if(ref_contact AND eval_contact) tp, "
            "count_if(NOT ref_contact AND eval_contact) fp, count_if(ref_contact AND NOT eval_contact) fn, "
            "count_if(NOT ref_contact AND NOT eval_contact) tn "
            f"FROM contact_pairs('human', 'real') WHERE sequence_id = '{seq}' GROUP BY region"
        )
        .df()
        .set_index("region")
    )
    for region, s in py.regions.items():
        assert tuple(int(x) for x in sql.loc[region, list(COUNT_COLUMNS)]) == (s.tp, s.fp, s.fn, s.tn)
    # The dropped samples are exactly those before the first reference sample.
    n_before = int((ev["t_ref"] < ref["t_ref"].min()).sum())
    n_pairs = con.execute(
        f"SELECT count(*) FROM contact_pairs('human', 'real') WHERE sequence_id = '{seq}'"
    ).fetchone()[0]
    assert n_pairs == len(ev) - n_before
    assert n_before > 0


def test_orphan_sequence_is_dropped(lake) -> None:
    con, _ = lake
    n = con.execute("SELECT count(*) FROM contact_pairs('human', 'sim') WHERE sequence_id = 'sim_orphan'").fetchone()[0]
    assert n == 0


def test_scalar_macros_null_for_zero_denominator() -> None:
    con = duckdb.connect()
    con.register("contacts", CONTACTS_SCHEMA.empty_table())
    register_contact_macros(con)
    row = con.execute(
        "SELECT contact_precision(0, 0), contact_recall(0, 0), contact_f1(0, 0, 0), contact_fpr(0, 0), "
        "contact_precision(1, 2), contact_f1(1, 1, 0)"
    ).fetchone()
    assert row == (None, None, None, None, 1 / 3, 2 / 3)
