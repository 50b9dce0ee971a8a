"""Tasks of the evaluation: contact metrics and onset errors per evaluated source, user-study
statistics per ratings file, lake writes, MLflow runs with figures, Prefect artefacts."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pandas as pd
import pyarrow as pa
from prefect import get_run_logger, task
from prefect.artifacts import create_markdown_artifact, create_table_artifact

from schemas.tables import SCHEMAS
from tasks import tracking
from tasks.common import ALWAYS_RUN, cache_policy
from touch2robot import evaluate as ev
from touch2robot.comparison.config import ComparisonConfig
from touch2robot.datasets import EVALUATION_IDS
from touch2robot.metrics import ALL
from touch2robot.settings import DataLayout

_LIBRARY = (
    "touch2robot.evaluate",
    "touch2robot.metrics",
    "touch2robot.stats",
    "touch2robot.lake",
    "touch2robot.datasets",
)

# Timelines drawn per (source, method, task) run: enough to see the agreement, few enough
# that the paper profile's hundreds of rollouts do not flood the artefact store.
TIMELINES_PER_RUN = 2

# The metrics every (source, task, method) run logs, NaN where undefined, so that the MLflow
# UI can compare every run on the same columns.
RUN_METRICS = (
    "precision",
    "recall",
    "f1",
    "fpr",
    "onset_error_ms",
    "onset_pairs",
    "tp",
    "fp",
    "fn",
    "tn",
    "n_sequences",
    "onset_missing_reference",
    "onset_missing_evaluated",
)


def _records(frame: pd.DataFrame, table: str) -> list[dict]:
    """Rows as plain dicts typed by the table's schema (NaN -> None): exact, picklable, hashable."""
    return pa.Table.from_pandas(frame, schema=SCHEMAS[table], preserve_index=False).to_pylist()


def _plain(frame: pd.DataFrame) -> list[dict]:
    """Rows of a frame with no lake schema as plain dicts (Python scalars: picklable, hashable)."""
    return pa.Table.from_pandas(frame, preserve_index=False).to_pylist()


def _frame(records: list[dict], table: str) -> pd.DataFrame:
    """The inverse of :func:`_records` (None -> NaN in float columns), columns in schema order."""
    return pa.Table.from_pylist(records, schema=SCHEMAS[table]).to_pandas()


@task(cache_policy=cache_policy(*_LIBRARY), persist_result=True, task_run_name="evaluate-{source}")
def evaluate_source(lake: str, source: str, reference: str, lake_digest: str) -> dict[str, list[dict]]:
    """Contact metrics and onset errors of one evaluated source vs the reference.

    ``lake_digest`` (:func:`touch2robot.datasets.folder_digest` of the folders it reads: their files'
    content) keys the cache on the data: a path alone would serve stale scores after the lake changed.
    """
    time_map = ev.read_time_map(Path(lake))
    metrics, onsets, clusters = [], [], []
    for seed, contacts in ev.per_seed(ev.read_contacts(Path(lake), [reference, source]), reference):
        scored = ev.onset_errors_table(contacts, time_map, source, reference).assign(seed=seed)
        metrics += _records(ev.contact_metrics_table(contacts, source, reference).assign(seed=seed), "contact_metrics")
        onsets += _records(scored, "onset_errors")
        clusters += _plain(ev.demonstration_sums(contacts, scored, source, reference).assign(seed=seed))
    return {"contact_metrics": metrics, "onset_errors": onsets, "clusters": clusters}


@task(cache_policy=cache_policy(*_LIBRARY, "touch2robot.ingest"), persist_result=True)
def evaluate_fidelity(lake: str, contact_threshold_n: float, lake_digest: str) -> dict[str, list[dict]]:
    """Tactile fidelity (the paper's second comparison): per robot replay that names its trajectory, the
    contacts the trajectory makes on the simulated target hand scored against those measured on the replay
    (reference ``real``), and the onset error between them on the reference clock. ``lake_digest`` covers
    the recordings, the contacts and the rollouts it reads."""
    no_time_map = SCHEMAS["time_map"].empty_table().to_pandas()  # both sides carry t_ref already
    demonstration_of = ev.replay_demonstrations(Path(lake))
    reference = ev.FIDELITY_REFERENCE
    metrics, onsets, sums = [], [], []
    for seed, contacts in ev.per_seed(ev.fidelity_contacts(Path(lake), contact_threshold_n), reference):
        for source in sorted(set(contacts["source"]) - {reference}):
            scored = ev.onset_errors_table(contacts, no_time_map, source, reference).assign(seed=seed)
            table = ev.contact_metrics_table(contacts, source, reference).assign(seed=seed)
            metrics += _records(table, "contact_metrics")
            onsets += _records(scored, "onset_errors")
            sums.append(ev.demonstration_sums(contacts, scored, source, reference, demonstration_of).assign(seed=seed))
    clusters = _plain(ev.pooled_as(pd.concat(sums, ignore_index=True), ev.FIDELITY_SOURCE)) if sums else []
    return {"contact_metrics": metrics, "onset_errors": onsets, "clusters": clusters}


@task(cache_policy=cache_policy(*_LIBRARY), persist_result=True)
def evaluate_ablations(lake: str, lake_digest: str) -> list[dict]:
    """The student ablations' clusters (table ``student_variants``); ``lake_digest`` covers that table."""
    return _plain(ev.ablation_sums(Path(lake)))


@task(cache_policy=cache_policy(*_LIBRARY, "touch2robot.comparison.statistics"), persist_result=True)
def compare_methods(clusters: list[dict], config: ComparisonConfig, seeds: list[int]) -> list[dict]:
    """The ``comparison`` rows: every method's (and student ablation's) scores with cluster-bootstrap intervals
    over demonstrations (the sweep's ``seeds`` pooled per demonstration; a cell lacking one says so), and each
    one's paired difference and Wilcoxon test against ``config.versus`` (an ablation: against its full model),
    Holm-adjusted."""
    from touch2robot.comparison.statistics import comparison_table

    frame = pd.DataFrame.from_records(clusters, columns=[*ev.CLUSTER_TABLE_COLUMNS, "variant", "seed"])
    table = comparison_table(
        frame, str(config.versus), config.confidence, config.n_resamples, config.seed, tuple(seeds)
    )
    return _records(table, "comparison")


@task(cache_policy=cache_policy(*_LIBRARY), persist_result=True, task_run_name="user-study-{ratings_sha256:.12}")
def evaluate_ratings(path: str, ratings_sha256: str) -> dict:
    """User-study statistics of one ratings CSV (keyed by its content hash).

    Ratings the statistics reject are reported with the reason instead of failing the whole
    evaluation (like a quarantined recording): ``rows`` is then empty and ``error`` says why.
    """
    name = Path(path).name
    synthetic = ev.is_synthetic(pd.DataFrame(), name)
    try:
        ratings = pd.read_csv(path)  # pandas' parse errors are ValueErrors too
        synthetic = ev.is_synthetic(ratings, name)
        rows = ev.user_study_table(ratings, name, ratings_sha256, synthetic)
    except ValueError as e:
        get_run_logger().warning("user-study ratings %s skipped: %s", path, e)
        return {"path": path, "synthetic": synthetic, "rows": [], "error": str(e)}
    return {"path": path, "synthetic": synthetic, "rows": _records(rows, "user_study"), "error": ""}


@task(**ALWAYS_RUN)
def store_table(lake: str, table: str, records: list[dict]) -> list[str]:
    """Replace an evaluation table's files with ``records`` (one file per group of the catalog's key columns).

    Not cached on purpose: it is cheap, and running it every time keeps the lake equal to the
    current results even if someone deleted files behind a cached computation.
    """
    return ev.replace_table(Path(lake), table, _frame(records, table), EVALUATION_IDS[table].columns)


def _summary(metrics: pd.DataFrame, onsets: pd.DataFrame) -> pd.DataFrame:
    """One row per (source, method, task incl. '*', seed): overall contact scores + onset summary."""
    keys = ["reference_source", "source", "method", "task", "seed"]
    m = metrics[metrics["region"] == ALL][
        [*keys, "n_sequences", "tp", "fp", "fn", "tn", "precision", "recall", "f1", "fpr"]
    ]
    o = onsets[(onsets["sequence_id"] == ALL) & (onsets["region"] == ALL)]
    o = o[[*keys, "error_ms", "n", "n_missing_reference", "n_missing_evaluated"]].rename(
        columns={
            "error_ms": "onset_error_ms",
            "n": "onset_pairs",
            "n_missing_reference": "onset_missing_reference",
            "n_missing_evaluated": "onset_missing_evaluated",
        }
    )
    return m.merge(o, on=keys, how="outer").sort_values(keys, ignore_index=True)


def _timelines(
    lake: Path, reference: str, source: str, method: str, task_name: str, seed: int, out: Path
) -> list[Path]:
    """Timeline figures of (source, method, task, seed) on its first few demonstrations (the first sequence of
    each) vs the reference, one file per demonstration, named by it: ``<out>/<demonstration>.png``."""
    contacts = ev.read_contacts(lake, [reference, source], task=task_name)
    mine = contacts[
        (contacts["source"] == source) & (contacts["method"] == method) & (contacts["seed"].fillna(0) == seed)
    ]
    ref = contacts[contacts["source"] == reference]
    firsts = mine.sort_values("sequence_id").drop_duplicates("reference_id")
    paths = []
    for seq, ref_id in sorted(zip(firsts["sequence_id"], firsts["reference_id"], strict=True), key=lambda p: p[1])[
        :TIMELINES_PER_RUN
    ]:
        rows = mine[mine["sequence_id"] == seq]
        title = f"{task_name}: {source}/{method} {seq} (lower) vs {reference} {ref_id} (upper)"
        png = out / f"{ev.file_id(ref_id)}.png"
        paths.append(ev.plot_timeline(ref[ref["sequence_id"] == ref_id], rows, title, png))
    return paths


@task(cache_policy=cache_policy(*_LIBRARY, "tasks.tracking"), persist_result=True)
def log_evaluation(
    data: str,
    profile: str,
    reference: str,
    contact_metrics: list[dict],
    onset_summaries: list[dict],
    lake_digest: str,
    tracking_uri: str,
) -> dict[str, str]:
    """One MLflow run per (source, task, method, seed) in the "evaluate" experiment, plus a summary run.

    Each run has params source/task/method/seed (task "*" = all tasks) and metrics precision, recall,
    f1, fpr, onset_error_ms, onset_pairs (N), the counts and per-region F1, and (per task) the
    contact timelines of a few sequences vs their reference. The summary run holds the
    metrics-by-method bar chart (seeds pooled) and the tables as CSV. Cached on the figures, the lake state
    (``lake_digest``: the timelines read it) and ``tracking_uri`` (another MLflow store is new
    work), so a re-run on unchanged data adds no duplicate runs.

    Returns:
        MLflow run id per run name.
    """
    import mlflow

    layout = DataLayout.from_env(data)
    metrics = _frame(contact_metrics, "contact_metrics")
    onsets = _frame(onset_summaries, "onset_errors")
    summary = _summary(metrics, onsets)
    runs: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for row in summary.to_dict(orient="records"):
            source, method, task_name, against = row["source"], row["method"], row["task"], row["reference_source"]
            seed = int(row["seed"])
            task_label = "all" if task_name == ALL else task_name  # MLflow's UI filters and sorts on plain words
            name = f"{source}/{method}/{task_label}/seed{seed}"
            if against != reference:  # tactile fidelity: scored against the replay's measured contacts
                name = f"fidelity/{name}"
            tags = {
                "kind": "method",
                "profile": profile,
                "reference_source": against,
                "source": source,
                "method": method,
                "task": task_label,
                "seed": str(seed),
            }
            with tracking.stage_run(layout, "evaluate", name, tags) as run:
                mlflow.log_params({"source": source, "task": task_label, "method": method, "seed": seed})
                values = {k: float(row[k]) for k in RUN_METRICS}
                regional = metrics[
                    (metrics["reference_source"] == against)
                    & (metrics["source"] == source)
                    & (metrics["method"] == method)
                    & (metrics["task"] == task_name)
                    & (metrics["seed"] == seed)
                    & (metrics["region"] != ALL)
                ]
                values |= {
                    f"f1/{region}": float(f1) for region, f1 in zip(regional["region"], regional["f1"], strict=True)
                }
                mlflow.log_metrics(values)
                if task_name != ALL and against == reference:
                    # named by demonstration, not method: MLflow's compare view lines the methods' figures up
                    for png in _timelines(layout.lake, reference, source, method, task_name, seed, out / name):
                        mlflow.log_artifact(str(png), f"contact_timelines/{task_name}")
                runs[name] = run.info.run_id
        with tracking.stage_run(
            layout, "evaluate", f"summary-{profile}", {"kind": "summary", "profile": profile}
        ) as run:
            pooled, pooled_onsets = ev.pool_seeds(metrics, onsets)
            for against, title in ((reference, "metrics_by_method"), (ev.FIDELITY_REFERENCE, "fidelity_by_method")):
                scored = pooled[pooled["reference_source"] == against]
                if len(scored):
                    against_onsets = pooled_onsets[pooled_onsets["reference_source"] == against]
                    mlflow.log_artifact(str(ev.plot_metrics_by_method(scored, against_onsets, out / f"{title}.png")))
            for name, frame in (("summary", summary), ("contact_metrics", metrics), ("onset_summaries", onsets)):
                frame.to_csv(out / f"{name}.csv", index=False)
                mlflow.log_artifact(str(out / f"{name}.csv"))
            runs[f"summary-{profile}"] = run.info.run_id
    return runs


@task(
    cache_policy=cache_policy(*_LIBRARY, "tasks.tracking"),
    persist_result=True,
    task_run_name="log-user-study-{ratings_sha256:.12}",
)
def log_user_study(data: str, profile: str, path: str, ratings_sha256: str, rows: list[dict], tracking_uri: str) -> str:
    """One MLflow run for a ratings file's user study: per-question metrics, the table, a box plot.

    SYNTHETIC ratings are labelled by the tag ``synthetic=true`` and in the run name, so the
    example numbers cannot pass for a study. Cached on the file's content hash and the store.
    """
    import mlflow

    layout = DataLayout.from_env(data)
    table = _frame(rows, "user_study")
    synthetic = bool(table["synthetic"].any())
    name = f"user-study-{Path(path).stem}" + (" (SYNTHETIC)" if synthetic else "")
    tags = {"kind": "user_study", "profile": profile, "synthetic": str(synthetic).lower()}
    with tracking.stage_run(layout, "evaluate", name, tags) as run, tempfile.TemporaryDirectory() as tmp:
        first = table.iloc[0]
        mlflow.log_params(
            {
                "ratings_file": Path(path).name,
                "ratings_sha256": ratings_sha256,
                "zero_method": first["zero_method"],
                "wilcoxon_method": first["method"],
                "correction": bool(first["correction"]),
                "n": int(first["n"]),
            }
        )
        for r in table.itertuples(index=False):
            mlflow.log_metrics(
                {
                    f"{key}/{r.question}": float(getattr(r, key))
                    for key in (
                        "p",
                        "p_holm",
                        "statistic",
                        "median_visual_feedback",
                        "median_touch2robot",
                        "iqr_visual_feedback",
                        "iqr_touch2robot",
                    )
                }
            )
        table.to_csv(Path(tmp) / "user_study.csv", index=False)
        mlflow.log_artifact(str(Path(tmp) / "user_study.csv"))
        title = f"{Path(path).name}{' — SYNTHETIC ratings, not a study' if synthetic else ''}"
        mlflow.log_artifact(str(ev.plot_ratings(pd.read_csv(path), title, Path(tmp) / "ratings.png")))
        return run.info.run_id


@task(**ALWAYS_RUN)
def publish_artefacts(
    profile: str, contact_metrics: list[dict], onset_summaries: list[dict], studies: list[dict], runs: dict[str, str]
) -> None:
    """Prefect artefacts of the flow run: the metrics table, the user-study table, a summary."""
    summary = _summary(_frame(contact_metrics, "contact_metrics"), _frame(onset_summaries, "onset_errors"))
    shown = summary[
        [
            "reference_source",
            "source",
            "method",
            "task",
            "seed",
            "n_sequences",
            "precision",
            "recall",
            "f1",
            "fpr",
            "onset_error_ms",
            "onset_pairs",
        ]
    ]
    create_table_artifact(
        key="evaluate-contact-metrics",
        # pandas-stubs gaps: where() takes None (JSON null for the artefact: NaN is no JSON),
        # and the records' keys are typed Hashable though these columns are named by str
        table=shown.round(4).astype(object).where(shown.notna(), None).to_dict(orient="records"),  # pyright: ignore[reportArgumentType]
        description=(
            f"Preference alignment (reference human) and tactile fidelity (reference real: the replay's measured "
            f"contacts) per source/method/task, with the onset error ({profile}; task '*' = all)"
        ),
    )
    study_rows = [r for s in studies for r in s["rows"]]
    if study_rows:
        create_table_artifact(
            key="evaluate-user-study",
            table=[
                {
                    k: r[k]
                    for k in (
                        "ratings_file",
                        "synthetic",
                        "question",
                        "n",
                        "median_visual_feedback",
                        "median_touch2robot",
                        "statistic",
                        "p",
                        "p_holm",
                    )
                }
                for r in study_rows
            ],
            description=(
                "Paired two-sided Wilcoxon signed-rank per question, Holm-corrected (synthetic = example ratings)"
            ),
        )
    lines = [f"# Evaluate ({profile})", "", f"{len(runs)} MLflow runs in experiment `touch2robot/evaluate`.", ""]
    for s in studies:
        label = " (SYNTHETIC)" if s["synthetic"] else ""
        status = f"skipped: {s['error']}" if s["error"] else f"{len(s['rows'])} questions"
        lines.append(f"- ratings `{Path(s['path']).name}`{label}: {status}")
    create_markdown_artifact(key="evaluate-summary", markdown="\n".join(lines) + "\n")
