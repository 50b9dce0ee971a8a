"""Flow `report`: the run's report (report.md, a self-contained report.html, a Prefect artefact and an
MLflow run) from the catalog's comparison, policy and user-study tables."""

from __future__ import annotations

from prefect import flow

from tasks import tracking
from tasks.common import stored, unvisited
from tasks.ingest import refresh_catalog
from tasks.report import build_report, learning_curves, learning_curves_of_server
from touch2robot.config import load_profile
from touch2robot.settings import DataLayout


@flow(name="report", log_prints=True)
def report(profile: str = "smoke", data: str | None = None, seeds: list[int] | None = None) -> dict:
    """Refresh the catalog and write the report of what it holds; ``profile`` names the run's settings and
    ``seeds`` (default the profile's) the sweep it reports, a figure lacking one of them saying so."""
    layout = DataLayout.from_env(data)
    load_profile(profile).sweep(seeds)  # bad seeds fail here, before the catalog is touched
    root, curves_cache = str(layout.root), stored(learning_curves, layout.results)
    refresh_catalog(root)
    store = tracking.store_digest(layout)  # None: a user's tracking server, whose curves are read every run
    curves = learning_curves_of_server(root) if store is None else curves_cache(root, store)
    written = build_report(root, profile, unvisited(curves), seeds)
    if store is not None and written["new"] and (logged := tracking.store_digest(layout)) is not None:
        # the report's own MLflow run changed the store: the curves (unchanged) are keyed on its new content too,
        # so that the next run on these results reads no MLflow
        curves_cache(root, logged)
    print(f"report: {written['html']}")
    return written
