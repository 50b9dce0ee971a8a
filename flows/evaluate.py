"""Flow `evaluate`: every evaluated contact source vs the human reference, and the user study
-> lake tables contact_metrics / onset_errors / comparison / user_study, MLflow runs, Prefect artefacts."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from prefect import flow, unmapped

from schemas.tables import SCHEMAS
from tasks import tracking
from tasks.common import stored, unvisited
from tasks.evaluate import (
    compare_methods,
    evaluate_ablations,
    evaluate_fidelity,
    evaluate_ratings,
    evaluate_source,
    log_evaluation,
    log_user_study,
    publish_artefacts,
    store_table,
)
from tasks.ingest import refresh_catalog
from tasks.runners import ProfileTaskRunner
from touch2robot.config import load_profile
from touch2robot.datasets import (
    CONTACTS,
    RECORDINGS,
    ROLLOUTS,
    STUDENT_VARIANTS,
    check_ids,
    file_digest,
    folder_digest,
)
from touch2robot.evaluate import (
    FIDELITY_REFERENCE,
    REFERENCE_SOURCE,
    evaluated_sources,
    pool_seeds,
    ratings_files,
    reported_studies,
    source_folders,
)
from touch2robot.metrics import ALL
from touch2robot.settings import DataLayout


@flow(name="evaluate", task_runner=ProfileTaskRunner(), log_prints=True)
def evaluate(
    profile: str = "smoke",
    data: str | None = None,
    ratings: str | None = None,
    reference: str = REFERENCE_SOURCE,
    seeds: list[int] | None = None,
) -> dict:
    """Score every contact source in the lake other than ``reference`` (all its methods and tasks:
    preference alignment), every replayed trajectory's contacts against those measured on its replay
    (tactile fidelity, reference ``real``), and the user-study ratings (``ratings``: a CSV or a folder of them, default
    ``<data>/recordings/user_study``); rewrite the evaluation tables, refresh the catalog, log
    MLflow runs. ``profile`` labels the runs; every sweep seed in the lake is scored, and the comparison
    reports a cell's missing seeds against ``seeds`` (default the profile's)."""
    layout = DataLayout.from_env(data)
    config = load_profile(profile)
    sweep = config.sweep(seeds)
    check_ids(layout.lake, ("contacts", "rollouts", "student_variants"))  # a stray file fails here, named
    lake = str(layout.lake)
    sources = evaluated_sources(layout.lake, reference)
    digests = [folder_digest(source_folders(layout.lake, s, reference)) for s in sources]
    per_source = [
        f.result()
        for f in stored(evaluate_source, layout.results).map(unmapped(lake), sources, unmapped(reference), digests)
    ]
    fidelity_folders = [CONTACTS.folder(layout.lake) / f"source={FIDELITY_REFERENCE}", ROLLOUTS.folder(layout.lake)]
    fidelity = stored(evaluate_fidelity, layout.results).submit(
        lake,
        config.teacher.sim.contact_threshold_n,
        folder_digest([*fidelity_folders, RECORDINGS.folder(layout.lake)]),
    )
    per_source.append(fidelity.result())
    paths = [str(p) for p in ratings_files(Path(ratings) if ratings else layout.user_study)]
    shas = [file_digest(p) for p in paths]
    evaluated = [f.result() for f in stored(evaluate_ratings, layout.results).map(paths, shas)]
    studies = reported_studies(evaluated)
    sha_of = dict(zip(paths, shas, strict=True))
    paths, shas = [s["path"] for s in studies], [sha_of[s["path"]] for s in studies]

    metrics = [r for s in per_source for r in s["contact_metrics"]]
    onsets = [r for s in per_source for r in s["onset_errors"]]
    ablations = stored(evaluate_ablations, layout.results)(lake, folder_digest([STUDENT_VARIANTS.folder(layout.lake)]))
    clusters = [r for s in per_source for r in s["clusters"]] + ablations
    comparison = stored(compare_methods, layout.results)(unvisited(clusters), config.comparison, list(sweep))
    store_table(lake, "contact_metrics", unvisited(metrics))
    store_table(lake, "onset_errors", unvisited(onsets))
    store_table(lake, "comparison", unvisited(comparison))
    store_table(lake, "user_study", unvisited([r for s in studies for r in s["rows"]]))
    refresh_catalog(str(layout.root))

    uri = tracking.tracking_uri(layout)
    summaries = [r for r in onsets if r["sequence_id"] == ALL]
    # a copy: the task's (possibly cached) result object is not ours to extend
    runs = dict(
        stored(log_evaluation, layout.results)(
            str(layout.root),
            profile,
            reference,
            unvisited(metrics),
            unvisited(summaries),
            folder_digest([CONTACTS.folder(layout.lake)]),
            uri,
        )
    )
    for path, sha, study in zip(paths, shas, studies, strict=True):
        if study["rows"]:
            runs[f"user-study-{Path(path).stem}"] = stored(log_user_study, layout.results)(
                str(layout.root), profile, path, sha, unvisited(study["rows"]), uri
            )
    publish_artefacts(profile, unvisited(metrics), unvisited(summaries), unvisited(studies), runs)
    pooled, _ = pool_seeds(
        pd.DataFrame(metrics, columns=SCHEMAS["contact_metrics"].names),
        pd.DataFrame(onsets, columns=SCHEMAS["onset_errors"].names),
    )
    overall = {  # over the sweep's seeds
        ("" if r["reference_source"] == reference else "fidelity:") + f"{r['source']}/{r['method']}": r["f1"]
        for r in pooled.to_dict("records")
        if r["task"] == ALL and r["region"] == ALL
    }
    print(
        f"evaluate: sources {sources}, {len(comparison)} comparison rows, {len(studies)} ratings file(s) -> "
        f"{layout.catalog}"
    )
    skipped = {Path(s["path"]).name: s["error"] for s in studies if s["error"]}
    return {
        "sources": sources,
        "f1": overall,
        # every method's F1 over all tasks with its interval and paired comparison (the comparison table's rows)
        "f1_compared": [r for r in comparison if r["task"] == ALL and r["metric"] == "f1"],
        "ratings": [Path(p).name for p in paths],
        # SYNTHETIC example ratings left out because real ratings exist
        "ratings_left_out": [Path(s["path"]).name for s in evaluated if s not in studies],
        "ratings_skipped": skipped,
        "runs": runs,
    }
