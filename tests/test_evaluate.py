"""Evaluation: table builders on hand-made contacts (known answers), lake writes, and the
`evaluate` flow end to end on a smoke pipeline output (Python == SQL, MLflow runs, re-runs)."""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import write_twin_replays

from schemas.tables import SCHEMAS, unseeded
from touch2robot import evaluate as ev
from touch2robot import lake as lake_io
from touch2robot.metrics import ALL
from touch2robot.stats import user_study
from touch2robot.synth.ratings import synthetic_ratings

os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")


def _seq(
    source: str,
    method: str,
    task: str,
    seq: str,
    ref: str,
    t: list[float],
    t_ref: list[float],
    contact: dict[str, list[int]],
) -> pd.DataFrame:
    """Long contacts rows of one sequence (one row per time x region)."""
    frames = [
        pd.DataFrame({"t": t, "t_ref": t_ref, "region": region, "contact": np.asarray(c, dtype=bool)})
        for region, c in contact.items()
    ]
    return pd.concat(frames, ignore_index=True).assign(
        source=source,
        method=method,
        task=task,
        subject="s01",
        sequence_id=seq,
        reference_id=ref,
        value=np.float32(np.nan),
    )


T4 = [0.0, 1.0, 2.0, 3.0]


@pytest.fixture
def scored() -> pd.DataFrame:
    """Human pick/wipe references, method m1 on both tasks, method m2 (never in contact) on pick."""
    return pd.concat(
        [
            _seq("human", "human", "pick", "h1", "h1", T4, T4, {"T1": [1, 1, 0, 0], "P1": [0, 0, 0, 0]}),
            _seq("human", "human", "wipe", "h2", "h2", T4, T4, {"T1": [1, 1, 0, 0], "P1": [0, 0, 0, 0]}),
            # own clock t differs from t_ref: only t_ref matters for the counts
            _seq("real", "m1", "pick", "r1", "h1", [10, 11, 12, 13], T4, {"T1": [1, 0, 1, 0], "P1": [0, 0, 0, 1]}),
            _seq("real", "m1", "wipe", "r2", "h2", T4, T4, {"T1": [1, 1, 0, 0], "P1": [0, 0, 0, 0]}),
            _seq("real", "m2", "pick", "r3", "h1", T4, T4, {"T1": [0, 0, 0, 0], "P1": [0, 0, 0, 0]}),
        ],
        ignore_index=True,
    )


def _row(table: pd.DataFrame, **keys: str) -> pd.Series:
    mask = np.ones(len(table), dtype=bool)
    for k, v in keys.items():
        mask &= (table[k] == v).to_numpy()
    assert mask.sum() == 1, keys
    return table[mask].iloc[0]


def test_contact_metrics_known_answers_and_rollups(scored: pd.DataFrame) -> None:
    table = ev.contact_metrics_table(scored, "real")
    assert list(table.columns) == unseeded("contact_metrics").names
    # m1: 2 tasks x 2 regions + 2 task totals + 2 region totals + 1 overall; m2: 2 + 1 + 2 + 1
    assert len(table) == 9 + 6
    t1 = _row(table, method="m1", task="pick", region="T1")
    assert (t1.tp, t1.fp, t1.fn, t1.tn) == (1, 1, 1, 1) and t1.f1 == 0.5
    p1 = _row(table, method="m1", task="pick", region="P1")
    assert (p1.tp, p1.fp, p1.fn, p1.tn) == (0, 1, 0, 3)
    assert p1.precision == 0 and math.isnan(p1.recall) and p1.fpr == 0.25
    pick = _row(table, method="m1", task="pick", region=ALL)
    assert (pick.tp, pick.fp, pick.fn, pick.tn, pick.n) == (1, 2, 1, 4, 8)
    assert pick.precision == pytest.approx(1 / 3) and pick.recall == 0.5 and pick.f1 == pytest.approx(0.4)
    assert pick.fpr == pytest.approx(2 / 6)
    overall = _row(table, method="m1", task=ALL, region=ALL)
    assert (overall.tp, overall.fp, overall.fn, overall.tn, overall.n_sequences) == (3, 2, 1, 10, 2)
    assert _row(table, method="m1", task=ALL, region="T1").tp == 3
    silent = _row(table, method="m2", task=ALL, region=ALL)
    assert math.isnan(silent.precision) and silent.recall == 0 and silent.f1 == 0 and silent.n_sequences == 1
    assert (table["source"] == "real").all() and (table["reference_source"] == "human").all()
    assert ev.contact_metrics_table(scored, "sim").empty  # a source with no rows


def test_onset_errors_pairs_and_summaries() -> None:
    human = _seq("human", "human", "pick", "h1", "h1", T4, T4, {"T1": [0, 1, 1, 0], "P1": [0, 0, 0, 0]})
    # replay clock runs twice as slow as the reference; the stored t_ref is deliberately off by
    # 0.25 s so the assertions show that the recorded time map, not t_ref, places the onset
    real = _seq(
        "real",
        "m",
        "pick",
        "r1",
        "h1",
        [0, 2, 4, 6],
        [0.25, 1.25, 2.25, 3.25],
        {"T1": [0, 0, 1, 1], "P1": [0, 1, 0, 0]},
    )
    time_map = pd.DataFrame({"recording_id": "r1", "t": [0.0, 6.0], "t_ref": [0.0, 3.0]})
    sim = pd.concat(
        [
            _seq("sim", "m", "pick", "s1", "h1", T4, T4, {"T1": [1, 1, 1, 1], "P1": [0, 0, 0, 0]}),
            _seq("sim", "m", "pick", "s2", "h1", T4, T4, {"T1": [0, 1, 0, 0], "P1": [0, 0, 0, 0]}),
        ]
    )
    contacts = pd.concat([human, real, sim], ignore_index=True)

    r = ev.onset_errors_table(contacts, time_map, "real")
    assert list(r.columns) == unseeded("onset_errors").names
    t1 = _row(r, sequence_id="r1", region="T1")
    assert t1.valid and t1.via_time_map and t1.t_eval_onset == 2.0 and t1.error_ms == pytest.approx(1000.0)
    p1 = _row(r, sequence_id="r1", region="P1")
    assert not p1.valid and math.isnan(p1.t_ref_onset) and p1.t_eval_onset == 1.0
    assert (p1.n_missing_reference, p1.n_missing_evaluated, p1.n_missing_both) == (1, 0, 0)
    summary = _row(r, task="pick", sequence_id=ALL, region=ALL)
    assert (summary.n_pairs, summary.n, summary.n_missing_reference) == (2, 1, 1)
    assert summary.error_ms == pytest.approx(1000.0) and pd.isna(summary.valid)

    s = ev.onset_errors_table(contacts, time_map, "sim")
    assert not s[s["sequence_id"] != ALL]["via_time_map"].any()  # rollouts use their stored t_ref
    assert _row(s, sequence_id="s1", region="T1").error_ms == pytest.approx(1000.0)
    assert _row(s, sequence_id="s2", region="T1").error_ms == pytest.approx(0.0)
    per_region = _row(s, task=ALL, sequence_id=ALL, region="T1")
    assert (per_region.n, per_region.error_ms) == (2, pytest.approx(500.0))
    overall = _row(s, task=ALL, sequence_id=ALL, region=ALL)
    assert (overall.n_pairs, overall.n, overall.n_missing_both) == (4, 2, 2)
    assert overall.error_ms == pytest.approx(500.0)
    no_valid = _row(s, task="pick", sequence_id=ALL, region="P1")
    assert no_valid.n == 0 and math.isnan(no_valid.error_ms)  # E undefined with N = 0


def test_replace_table_rewrites_and_prunes(scored: pd.DataFrame, tmp_path: Path) -> None:
    lake = tmp_path / "lake"
    table = ev.contact_metrics_table(scored, "real").assign(seed=0)  # the evaluate task adds the sweep seed
    assert ev.replace_table(lake, "contact_metrics", table, ["source", "method"]) == ["real__m1", "real__m2"]
    assert ev.replace_table(lake, "contact_metrics", table, ["source", "method"]) == ["real__m1", "real__m2"]
    stored = pa.concat_tables(pq.read_table(p) for p in lake_io.files(lake, "contact_metrics"))
    assert stored.num_rows == len(table)  # rewriting replaced, did not append
    silent = stored.to_pandas().query("method == 'm2' and task == '*' and region == '*'").iloc[0]
    assert silent["precision"] is None or math.isnan(silent["precision"])
    assert stored.column("precision").null_count > 0  # 0/0 is NULL in the lake, for SQL
    ev.replace_table(lake, "contact_metrics", table[table["method"] == "m1"], ["source", "method"])
    assert [p.name for p in lake_io.files(lake, "contact_metrics")] == ["real__m1.parquet"]
    ev.replace_table(lake, "contact_metrics", table.iloc[:0], ["source", "method"])
    assert lake_io.files(lake, "contact_metrics") == []


def test_file_id_is_safe_and_unique() -> None:
    assert ev.file_id("real", "touch2robot") == "real__touch2robot"
    a, b = ev.file_id("sim", "a/b"), ev.file_id("sim", "a b")
    assert a != b and "/" not in a and a.startswith("sim__a-b-")
    assert not ev.file_id(".hidden").startswith(".")


def test_lake_reading_sources_and_digest(scored: pd.DataFrame, tmp_path: Path) -> None:
    lake = tmp_path / "lake"
    for (source, task, seq), rows in scored.groupby(["source", "task", "sequence_id"]):
        lake_io.write_rows(
            lake,
            "contacts",
            str(seq),
            pa.Table.from_pandas(rows, preserve_index=False),
            {"source": str(source), "task": str(task)},
        )
    assert ev.evaluated_sources(lake) == ["real"]
    back = ev.read_contacts(lake, ["human", "real"])
    assert len(back) == len(scored) and list(back.columns) == list(ev.CONTACT_COLUMNS)
    assert set(ev.read_contacts(lake, ["real"], task="wipe")["sequence_id"]) == {"r2"}
    folders = ev.source_folders(lake, "real")
    before = ev.folder_digest(folders)
    assert ev.folder_digest(folders) == before
    extra = scored[scored["sequence_id"] == "r3"].assign(sequence_id="r4")
    lake_io.write_rows(
        lake, "contacts", "r4", pa.Table.from_pandas(extra, preserve_index=False), {"source": "real", "task": "pick"}
    )
    assert ev.folder_digest(folders) != before
    assert ev.folder_digest(ev.source_folders(lake, "sim")) != ev.folder_digest(folders)


def test_user_study_table_and_synthetic_flag() -> None:
    ratings = synthetic_ratings(10, seed=3)
    table = ev.user_study_table(
        ratings, "ratings_SYNTHETIC.csv", "abc", ev.is_synthetic(ratings, "ratings_SYNTHETIC.csv")
    )
    assert list(table.columns) == SCHEMAS["user_study"].names
    expected = user_study(ratings).to_frame()
    assert list(table["question"]) == ["Q1", "Q2", "Q3", "Q4"]
    np.testing.assert_allclose(table["p_holm"], expected["p_holm"])
    np.testing.assert_allclose(table["statistic"], expected["statistic"])
    assert (
        table["synthetic"].all()
        and (table["zero_method"] == "wilcox").all()
        and (table["method"] == "asymptotic").all()
    )
    real = ratings.drop(columns="synthetic")
    assert not ev.is_synthetic(real, "ratings.csv")
    assert ev.is_synthetic(real, "study_synthetic.csv")
    assert ev.is_synthetic(real.assign(synthetic=[False] * (len(real) - 1) + [True]), "ratings.csv")
    with pytest.raises(ValueError, match="participant"):
        ev.user_study_table(real.iloc[1:], "ratings.csv", "abc", False)


def test_figures_render(scored: pd.DataFrame, tmp_path: Path) -> None:
    metrics = ev.contact_metrics_table(scored, "real")
    onsets = ev.onset_errors_table(scored, pd.DataFrame(columns=["recording_id", "t", "t_ref"]), "real")
    paths = [
        ev.plot_metrics_by_method(metrics, onsets, tmp_path / "bars.png"),
        ev.plot_timeline(
            scored[scored["sequence_id"] == "h1"], scored[scored["sequence_id"] == "r1"], "r1", tmp_path / "t.png"
        ),
        ev.plot_ratings(synthetic_ratings(), "SYNTHETIC", tmp_path / "r.png"),
    ]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- the flow


def _table(data: Path, sql: str) -> pd.DataFrame:
    from touch2robot import catalog
    from touch2robot.settings import DataLayout

    return catalog.query(DataLayout.from_env(data), sql).to_pandas()


def _evaluate_runs(data: Path) -> pd.DataFrame:
    import mlflow

    from tasks import tracking
    from touch2robot.settings import DataLayout

    exp = tracking.experiment(DataLayout.from_env(data), "evaluate")
    return mlflow.search_runs([exp])


def _counts(data: Path) -> dict[str, int]:
    return {
        t: int(_table(data, f"SELECT count(*) AS n FROM {t}")["n"].iloc[0])
        for t in ("contact_metrics", "onset_errors", "user_study")
    }


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The smoke demonstrator's recordings, a scripted grasp replayed on the hardware twin per glove session
    (``write_twin_replays``) and ingested, then one `evaluate` flow run on it."""
    from flows.evaluate import evaluate
    from flows.ingest import ingest
    from flows.synth import synth

    data = tmp_path_factory.mktemp("evaluate") / "data"
    synth(profile="smoke", data=str(data))
    write_twin_replays(data)
    ingest(profile="smoke", data=str(data))
    return data, evaluate(profile="smoke", data=str(data))


def test_flow_writes_sane_tables(evaluated: tuple[Path, dict]) -> None:
    data, result = evaluated
    assert result["sources"] == ["real"] and result["ratings"] == ["ratings_SYNTHETIC.csv"]
    m = _table(data, "SELECT * FROM contact_metrics WHERE region = '*' AND reference_source = 'human'")
    overall = _row(m, source="real", method="touch2robot", task=ALL)
    # a scripted grasp follows no human preference: the figures are what they are, but well defined
    assert overall.n_sequences == 4 and 0 <= overall.f1 <= 1 and 0 <= overall.fpr <= 1
    assert set(m["task"]) == {"pick", "rotate", "wipe", "drawer", ALL}
    o = _table(data, "SELECT * FROM onset_errors WHERE reference_source = 'human'")
    pairs = o[o["sequence_id"] != ALL]
    assert len(pairs) == 4 * 8 and pairs["via_time_map"].all()  # 4 replays x 8 regions, all mapped
    summary = o[(o["sequence_id"] == ALL) & (o["region"] == ALL) & (o["task"] != ALL)]
    assert len(summary) == 4 and (summary["n"] > 0).all() and np.isfinite(summary["error_ms"]).all()
    valid = pairs[pairs["valid"]]
    total = _row(o, task=ALL, sequence_id=ALL, region=ALL)
    assert total.n == len(valid) and total.error_ms == pytest.approx(valid["error_ms"].mean())
    u = _table(data, "SELECT * FROM user_study ORDER BY question")
    assert list(u["question"]) == ["Q1", "Q2", "Q3", "Q4"] and u["synthetic"].all()
    assert ((u["p"] > 0) & (u["p"] <= u["p_holm"]) & (u["p_holm"] <= 1)).all()


def test_flow_tables_equal_the_sql_macros(evaluated: tuple[Path, dict]) -> None:
    data, _ = evaluated
    keys = ["method", "task", "region"]
    python = _table(data, "SELECT * FROM contact_metrics WHERE source = 'real'").sort_values(keys, ignore_index=True)
    assert (python["reference_source"] == "human").all()
    sql = _table(data, "SELECT * FROM contact_score_slices('human', 'real') WHERE subject = '*'").sort_values(
        keys, ignore_index=True
    )
    assert len(python) == len(sql) == 4 * 8 + 4 + 8 + 1
    pd.testing.assert_frame_equal(
        python[[*keys, "tp", "fp", "fn", "tn"]], sql[[*keys, "tp", "fp", "fn", "tn"]], check_dtype=False
    )
    np.testing.assert_allclose(python["f1"].astype(float), sql["f1"].astype(float), rtol=1e-12)


def test_flow_logs_mlflow_runs_and_figures(evaluated: tuple[Path, dict]) -> None:
    import mlflow

    data, result = evaluated
    runs = _evaluate_runs(data)
    method_runs = runs[runs["tags.kind"] == "method"]
    assert (
        set(method_runs["params.task"]) == set(method_runs["tags.task"]) == {"pick", "rotate", "wipe", "drawer", "all"}
    )
    assert set(method_runs["tags.method"]) == {"touch2robot"} and set(method_runs["tags.stage"]) == {"evaluate"}
    fidelity = method_runs["tags.reference_source"] == "real"
    assert set(method_runs[~fidelity]["params.source"]) == {"real"} and set(method_runs["params.method"]) == {
        "touch2robot"
    }
    assert set(method_runs[fidelity]["params.source"]) == {"sim"}
    assert method_runs[fidelity]["tags.mlflow.runName"].str.startswith("fidelity/sim/touch2robot/").all()
    method_runs = method_runs[~fidelity]
    for column in ("precision", "recall", "f1", "fpr", "onset_error_ms", "onset_pairs"):
        assert method_runs[f"metrics.{column}"].notna().all(), column
    study = runs[runs["tags.kind"] == "user_study"]
    assert (
        len(study) == 1
        and study["tags.synthetic"].iloc[0] == "true"
        and "SYNTHETIC" in study["tags.mlflow.runName"].iloc[0]
    )
    client = mlflow.MlflowClient()
    pick = method_runs[method_runs["params.task"] == "pick"]["run_id"].iloc[0]
    # named by the demonstration (the glove recording), so MLflow's compare view lines the methods up
    pick_demo = _table(data, "SELECT recording_id FROM recordings WHERE task = 'pick' AND kind = 'glove_session'")
    assert [a.path for a in client.list_artifacts(pick, "contact_timelines/pick")] == [
        f"contact_timelines/pick/{pick_demo['recording_id'].item()}.png"
    ]
    assert "f1/T1" in client.get_run(pick).data.metrics
    summary = runs[runs["tags.kind"] == "summary"]["run_id"].iloc[0]
    assert {"metrics_by_method.png", "fidelity_by_method.png"} <= {a.path for a in client.list_artifacts(summary)}
    assert set(result["runs"].values()) == set(runs["run_id"])


def test_flow_scores_tactile_fidelity_against_the_replays(evaluated: tuple[Path, dict]) -> None:
    """Tactile fidelity: each replayed trajectory's simulated contacts against those measured on its replay."""
    data, result = evaluated
    m = _table(data, "SELECT * FROM contact_metrics WHERE reference_source = 'real' AND region = '*'")
    assert set(m["source"]) == {"sim"} and set(m["method"]) == {"touch2robot"}
    overall = _row(m, task=ALL)
    assert overall.n_sequences == 4 and overall.f1 > 0.7, overall
    assert result["f1"]["fidelity:sim/touch2robot"] == pytest.approx(overall.f1)
    o = _table(data, "SELECT * FROM onset_errors WHERE reference_source = 'real' AND sequence_id <> '*'")
    assert len(o) == 4 * 8 and not o["via_time_map"].any()  # both sides already on the reference clock
    assert (o[o["valid"]]["error_ms"] < 500).all()


def test_flow_compares_the_methods_over_demonstrations(evaluated: tuple[Path, dict]) -> None:
    """The comparison table's pooled estimates are contact_metrics' and onset_errors' figures, with
    intervals over the demonstrations; fidelity's replays count as the glove sessions they followed."""
    data, _ = evaluated
    c = _table(data, "SELECT * FROM comparison")
    assert set(zip(c["reference_source"], c["source"], strict=True)) == {("human", "real"), ("real", "sim")}
    assert set(c["metric"]) == {"precision", "recall", "f1", "fpr", "onset_error_ms"}
    m = _table(data, "SELECT * FROM contact_metrics WHERE region = '*'")
    o = _table(data, "SELECT * FROM onset_errors WHERE sequence_id = '*' AND region = '*'")
    for row in c.to_dict("records"):
        keys = {k: str(row[k]) for k in ("reference_source", "source", "task")}
        scored = _row(o, **keys)["error_ms"] if row["metric"] == "onset_error_ms" else _row(m, **keys)[row["metric"]]
        assert row["estimate"] == pytest.approx(scored, nan_ok=True), row
        assert row["n_demonstrations"] == (4 if row["task"] == ALL else 1) and row["versus"] is None
        if row["n_demonstrations"] > 1 and np.isfinite(row["estimate"]):
            assert row["ci_low"] <= row["estimate"] <= row["ci_high"], row


def test_flow_rerun_replaces_and_follows_the_sources(evaluated: tuple[Path, dict]) -> None:
    from flows.evaluate import evaluate

    data, _ = evaluated
    counts, n_runs = _counts(data), len(_evaluate_runs(data))
    evaluate(profile="smoke", data=str(data))
    assert _counts(data) == counts  # replaced, not appended
    assert len(_evaluate_runs(data)) == n_runs  # unchanged data: cached, no duplicate MLflow runs

    # a new source with another method (a rollout on the reference clock) is picked up: it copies
    # the real contacts on t_ref, so its counts must equal the real ones
    lake = data / "lake"
    real = ev.read_contacts(lake, ["real"])
    sim = real.assign(
        source="sim",
        method="contrack",
        sequence_id="sim-" + real["sequence_id"],
        t=real["t_ref"],
        value=np.float32(np.nan),
    )
    for task, rows in sim.groupby("task"):
        lake_io.write_rows(
            lake,
            "contacts",
            "teacher-contrack-seed0",  # a teacher's contacts, as the teachers stage names them
            pa.Table.from_pandas(rows, preserve_index=False),
            {"source": "sim", "task": str(task)},
        )
    evaluate(profile="smoke", data=str(data))
    m = _table(data, "SELECT * FROM contact_metrics WHERE reference_source = 'human'")
    count_cols = ["task", "region", "tp", "fp", "fn", "tn"]
    pd.testing.assert_frame_equal(
        m[m["source"] == "sim"][count_cols].sort_values(["task", "region"], ignore_index=True),
        m[m["source"] == "real"][count_cols].sort_values(["task", "region"], ignore_index=True),
    )
    o = _table(
        data, "SELECT * FROM onset_errors WHERE source = 'sim' AND sequence_id <> '*' AND reference_source = 'human'"
    )
    assert len(o) == 4 * 8 and not o["via_time_map"].any()
    runs = _evaluate_runs(data)
    assert {"sim/contrack/all/seed0", "real/touch2robot/all/seed0"} <= set(runs["tags.mlflow.runName"])

    shutil.rmtree(lake / "contacts" / "source=sim")
    # an unpaired ratings file is reported and skipped, like a quarantined recording
    bad = synthetic_ratings(4).iloc[1:].drop(columns="synthetic")
    bad.to_csv(data / "recordings" / "user_study" / "ratings_bad.csv", index=False)
    result = evaluate(profile="smoke", data=str(data))
    assert _counts(data) == counts  # the removed source's rows are gone, not kept stale
    assert (
        list(result["ratings_skipped"]) == ["ratings_bad.csv"]
        and "lacks one condition" in result["ratings_skipped"]["ratings_bad.csv"]
    )
