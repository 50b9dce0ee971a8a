"""The report task: the catalog's comparison, policy and user-study tables -> report.md and a
self-contained report.html under <data>/reports/<profile>-<digest>/, a Prefect markdown artefact and
an MLflow run holding the page."""

from __future__ import annotations

import dataclasses
import time

import pandas as pd
from prefect import get_run_logger, task
from prefect.artifacts import create_markdown_artifact

from tasks import tracking
from tasks.common import ALWAYS_RUN, cache_policy
from touch2robot import catalog
from touch2robot import lake as lake_io
from touch2robot import report as rp
from touch2robot.config import load_profile
from touch2robot.provenance import code_version
from touch2robot.settings import DataLayout

# Per task, the first demonstration replayed on the robot: the human's contacts and every method's measured ones
# on the replays of one sweep seed ($seed)
TIMELINES_SQL = """
WITH chosen AS (
  SELECT task, min(reference_id) AS reference_id FROM contacts
  WHERE source = 'real' AND coalesce(seed, 0) = $seed GROUP BY task
)
SELECT c.source, c.method, c.task, c.reference_id, c.t_ref, c.region, c.contact
FROM contacts c JOIN chosen USING (task, reference_id)
WHERE c.source = 'human' OR (c.source = 'real' AND coalesce(c.seed, 0) = $seed)
"""


# (stage, the metric its training runs log, the run tags that name a curve's panel and its line)
CURVES = (
    ("teachers", "Train/mean_reward", "task", "method"),
    ("student", "val/loss", None, "variant"),
    ("policy", "train/loss", "task", "method"),
)


def read_learning_curves(data: str) -> pd.DataFrame:
    """The training curves of the stages' MLflow runs (rows stage, panel, series, step, value); a stage
    that has not run has none."""
    import mlflow

    layout = DataLayout.from_env(data)
    mlflow.set_tracking_uri(tracking.tracking_uri(layout))
    client = mlflow.MlflowClient()
    rows = []
    for stage, metric, panel, series in CURVES:
        experiment = client.get_experiment_by_name(f"touch2robot/{stage}")
        if experiment is None:
            continue
        for run in client.search_runs([experiment.experiment_id]):
            tags = run.data.tags
            if metric not in run.data.metrics or series not in tags:  # e.g. the kinematic replays' runs
                continue
            label = tags[panel] if panel else "all"
            seed = tags.get("seed", "all")
            rows += [
                {"stage": stage, "panel": label, "series": tags[series], "seed": seed, "step": m.step, "value": m.value}
                for m in client.get_metric_history(run.info.run_id, metric)
            ]
    curves = pd.DataFrame(rows, columns=["stage", "panel", "series", "seed", "step", "value"])
    # one line per seed where a stage ran several (one line through all of them would zigzag)
    swept = curves.groupby("stage")["seed"].transform("nunique") > 1
    curves.loc[swept, "series"] = curves.loc[swept, "series"] + " seed " + curves.loc[swept, "seed"]
    return curves.drop(columns="seed")


@task(cache_policy=cache_policy("tasks.report", "tasks.tracking"), persist_result=True)
def learning_curves(data: str, store: str) -> pd.DataFrame:
    """``read_learning_curves``, keyed on the local tracking store's content (``store``,
    tasks.tracking.store_digest): a re-run that logged nothing opens no MLflow store (importing MLflow and
    opening its store are about 3 s of a cached smoke re-run on 2 cores)."""
    return read_learning_curves(data)


# a user's tracking server has no content digest here (tasks.tracking.store_digest)
learning_curves_of_server = task(**ALWAYS_RUN, name="learning_curves_of_server")(read_learning_curves)


@task(**ALWAYS_RUN)
def build_report(data: str, profile: str, curves: pd.DataFrame, seeds: list[int] | None = None) -> dict:
    """Write the run's report from the catalog (refreshed first by the caller) and the stages' MLflow
    ``curves``, and publish it. Its folder is named by the digest of everything it shows: a re-run on unchanged
    results finds the report already there and adds no MLflow run; changed results make a new one beside it."""
    layout = DataLayout.from_env(data)
    config = load_profile(profile)
    sweep = config.sweep(seeds)
    rows = {
        name: catalog.query(layout, f"SELECT * FROM {name}") for name in ("comparison", "policy_eval", "user_study")
    }
    tables = {name: table.to_pandas() for name, table in rows.items()}
    timeline_rows = catalog.query(layout, TIMELINES_SQL.replace("$seed", str(int(sweep[0]))))
    timelines = timeline_rows.to_pandas()
    versus = str(config.comparison.versus)
    provenance = {
        "profile": config.name,
        "created": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "seeds": (
            f"{len(sweep)} sweep seed(s) {', '.join(map(str, sweep))}, each added to every stage's own: teachers "
            f"{config.teacher.seed}, student {config.student.seed} (its held-out split stays that of "
            f"{config.student.seed}), replay {config.replay.seed}, policy {config.policy.seed}; bootstrap "
            f"{config.comparison.seed}; contact timelines from seed {sweep[0]}"
        ),
        "compared with": versus,
        "code": code_version(),
        "data": f"{layout.root} (tables digest {rp.table_digest(*rows.values())})",
    }
    # the tables are in the provenance's digest
    shown = rp.table_digest(timeline_rows, curves, pd.DataFrame([provenance]).drop(columns="created"))
    folder = layout.reports / f"{config.name}-{shown}"
    report = rp.ReportData(
        tables["comparison"], tables["policy_eval"], tables["user_study"], provenance, timelines, curves, seeds=sweep
    )
    found = rp.claims(report.comparison, rp.pooled_policy(report.policy, sweep), versus)
    markdown, page, run_file = folder / "report.md", folder / "report.html", folder / "mlflow_run_id"
    new = not (markdown.is_file() and page.is_file() and run_file.is_file())
    if new:
        import mlflow  # here: a report found already written needs no MLflow (about 1 s to import)

        report = dataclasses.replace(report, figures=rp.draw_figures(report))
        markdown, page = rp.write_report(folder, report, versus)
        tags = {"profile": config.name, "code": provenance["code"], "compared_with": versus}
        with tracking.stage_run(layout, "report", f"report-{config.name}", tags) as run:
            mlflow.log_artifact(str(page))
            mlflow.log_artifact(str(markdown))
        lake_io.replace_text(run.info.run_id, run_file)
    create_markdown_artifact(markdown.read_text(), key="report", description=f"touch2robot report, {config.name}")
    get_run_logger().info("report: %s (%d claims stated)", page, len(found))
    return {
        "folder": str(folder),
        "html": str(page),
        "markdown": str(markdown),
        "claims": [dataclasses.asdict(c) for c in found],
        "mlflow_run": run_file.read_text().strip(),
        "new": new,
    }
