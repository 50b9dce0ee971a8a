"""The report: the `report` flow over a catalog holding a comparison, policy results and a user study
writes report.md and a self-contained report.html that a real browser (Debian's Chromium, headless,
driven by Playwright) renders whole, states the paper's claims from the intervals, and is published
as a Prefect artefact and an MLflow run."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest
from conftest import comparison_clusters

from schemas.tables import SCHEMAS
from touch2robot import lake as lake_io
from touch2robot.comparison.statistics import comparison_table, wilson_interval
from touch2robot.evaluate import user_study_table
from touch2robot.metrics import ALL
from touch2robot.provenance import code_version
from touch2robot.report import claims
from touch2robot.synth.ratings import synthetic_ratings

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
METHODS = ("touch2robot", "contrack", "dexmachina", "dex-retargeting")


def _clusters() -> pd.DataFrame:
    """Four methods on the same 6 demonstrations of two tasks, for fidelity and preference alignment."""
    skills: dict[str, float] = dict(zip(METHODS, (0.9, 0.6, 0.62, 0.4), strict=True))
    return comparison_clusters(skills, (("real", "sim"), ("human", "real")), n_demos=6)


def _policy_rows() -> pd.DataFrame:
    rows = []
    for task, successes in (("pick", (9, 2, 3, 0)), ("rotate", (5, 4, 6, 1))):
        for method, k in zip(METHODS, successes, strict=True):
            low, high = wilson_interval(k, 10)
            rows.append(
                {
                    "task": task,
                    "method": method,
                    "seed": 0,
                    "origin": "teacher",
                    "observation": "images",
                    "profile": "smoke",
                    "dataset_episodes": 4,
                    "dataset_frames": 400,
                    "train_steps": 50,
                    "final_loss": 0.1,
                    "episodes": 10,
                    "successes": k,
                    "success_rate": k / 10,
                    "ci_low": low,
                    "ci_high": high,
                    "mean_progress": 0.5,
                    "replay_successes": 5,
                    "replay_success_rate": 0.5,
                    "fit_joint_err_rad": 0.01,
                    "fit_wrist_err_mm": 1.0,
                    "hold_joint_err_rad": 0.01,
                    "hold_wrist_err_mm": 1.0,
                    "episode_steps": 100,
                    "replans": 7,
                    "mlflow_run": "none",
                }
            )
    return pd.DataFrame(rows)


def _write(lake: Path, table: str, file_id: str, frame: pd.DataFrame) -> None:
    lake_io.write_rows(lake, table, file_id, pa.Table.from_pandas(frame, schema=SCHEMAS[table], preserve_index=False))


@pytest.fixture(scope="module")
def reported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, pd.DataFrame]:
    from flows.report import report

    data = tmp_path_factory.mktemp("report") / "data"
    comparison = comparison_table(_clusters(), versus="touch2robot", n_resamples=2000)
    _write(data / "lake", "comparison", "all", comparison)
    _write(data / "lake", "policy_eval", "all", _policy_rows())
    ratings = synthetic_ratings()
    _write(data / "lake", "user_study", "ratings", user_study_table(ratings, "ratings_SYNTHETIC.csv", "0" * 64, True))
    _log_teacher_curves(data)
    return data, report(profile="smoke", data=str(data)), comparison


def _log_teacher_curves(data: Path) -> None:
    """Two teachers' reward curves in MLflow, as the teachers stage logs them."""
    import mlflow

    from tasks import tracking
    from touch2robot.settings import DataLayout

    for method, rewards in (("touch2robot", (1.0, 2.0, 3.5)), ("contrack", (0.5, 1.5, 1.7))):
        tags = {"method": method, "task": "pick"}
        with tracking.stage_run(DataLayout.from_env(data), "teachers", f"teacher-pick-{method}", tags):
            for step, reward in enumerate(rewards):
                mlflow.log_metric("Train/mean_reward", reward, step=step)


def test_the_report_states_each_claim_from_its_interval(reported) -> None:
    _, result, comparison = reported
    found = {c["statement"]: c for c in result["claims"]}
    f1 = comparison[(comparison["task"] == ALL) & (comparison["metric"] == "f1") & comparison["versus"].notna()]
    assert len([s for s in found if " F1 " in s]) == len(f1) == 6  # 3 baselines x 2 scored sources
    for row in f1.to_dict("records"):
        scope = (
            "tactile fidelity"
            if row["reference_source"] == "real"
            else f"preference alignment, {row['source']} contacts"
        )
        claim = found[f"touch2robot has a higher F1 than {row['method']} ({scope})"]
        low, high = row["difference_ci_low"], row["difference_ci_high"]
        expected = "holds" if low > 0 else "does not hold" if high < 0 else "not resolved"
        assert claim["verdict"] == expected, (row, claim)
    policy = [c for s, c in found.items() if s.startswith("a policy")]
    assert len(policy) == 6  # 3 baselines x 2 tasks
    pick_vs_dex = next(c for c in policy if "dex-retargeting's (pick)" in c["statement"])
    assert pick_vs_dex["verdict"] == "holds"  # 9/10 [0.60, 0.98] vs 0/10 [0.00, 0.28]
    rotate_vs_dexmachina = next(c for c in policy if "dexmachina's (rotate)" in c["statement"])
    assert rotate_vs_dexmachina["verdict"] == "not resolved"  # 5/10 vs 6/10: the intervals overlap


def test_claims_of_a_missing_or_reversed_comparison_say_so() -> None:
    comparison = comparison_table(_clusters(), versus="contrack", n_resamples=500)
    found = claims(comparison, _policy_rows().iloc[:0], "contrack")
    over_dex = [c for c in found if "F1 than dex-retargeting" in c.statement]
    assert over_dex and all(c.verdict == "holds" for c in over_dex)
    over_t2r = [c for c in found if "F1 than touch2robot" in c.statement]
    assert over_t2r and all(c.verdict == "does not hold" for c in over_t2r)
    lone = _policy_rows()
    lone = lone[lone["method"] != "contrack"]
    assert {c.verdict for c in claims(comparison.iloc[:0], lone, "contrack")} == {"not measured"}


def test_the_report_is_published_as_files_an_artefact_and_an_mlflow_run(reported, monkeypatch) -> None:
    import mlflow

    from tasks import tracking
    from touch2robot.settings import DataLayout

    data, result, _ = reported
    page, markdown = Path(result["html"]), Path(result["markdown"])
    assert page.parent.parent == data / "reports" and markdown.parent == page.parent
    text = markdown.read_text()
    for heading in ("## What this run found", "Tactile fidelity", "Preference alignment", "## Policy success"):
        assert heading in text, heading
    assert "## User study" in text and "(SYNTHETIC)" in text and "| code | git " in text
    assert "## Learning curves: PPO teachers" in text and "Learning curves: Distilled student" not in text
    assert "| method | precision | recall | F1 | false-positive rate |" in text
    experiment = tracking.experiment(DataLayout.from_env(data), "report")
    client = mlflow.MlflowClient()
    assert {a.path for a in client.list_artifacts(result["mlflow_run"])} == {"report.html", "report.md"}
    # every run names the code that made it, and each stage's experiment says what it holds
    tags = client.get_run(result["mlflow_run"]).data.tags
    assert tags["stage"] == "report" and tags["code"] == code_version() and tags["code"].startswith("git ")
    assert tags["code"].split()[1] == tags["mlflow.source.git.commit"]
    assert client.get_experiment(experiment).tags["mlflow.note.content"].startswith("The run's report")
    # the same results again: the same report, no second MLflow run, and the curves from the cache (keyed on
    # the store's content after the report's own run), so MLflow's store is not read
    import tasks.report
    from flows.report import report

    def unread(data: str):
        raise AssertionError("the learning curves were read from MLflow again")

    store = tracking.store_digest(DataLayout.from_env(data))
    monkeypatch.setattr(tasks.report, "read_learning_curves", unread)
    again = report(profile="smoke", data=str(data))
    assert (again["html"], again["mlflow_run"], again["new"]) == (result["html"], result["mlflow_run"], False)
    assert len(client.search_runs([experiment])) == 1
    assert tracking.store_digest(DataLayout.from_env(data)) == store


def _browser():
    """Headless Debian Chromium under Playwright (.ci/run installs the package, as the README says)."""
    if not Path(CHROMIUM).is_file():
        pytest.fail(
            f"the report's browser test needs Debian's chromium: {CHROMIUM} is missing (apt-get install chromium)"
        )
    from playwright.sync_api import sync_playwright

    return sync_playwright()


def test_a_headless_chromium_renders_every_table_and_figure_of_the_page(reported, tmp_path: Path) -> None:
    _, result, _ = reported
    with _browser() as playwright:
        browser = playwright.chromium.launch(
            executable_path=CHROMIUM,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update"],
        )
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 900})
            requests: list[str] = []
            page.on("request", lambda r: requests.append(r.url))
            page.goto(Path(result["html"]).as_uri())
            page.wait_for_load_state("load")
            tables = page.locator("table")
            images = page.locator("img")
            # provenance, 2 scored sources x (all-task scores, F1 by task, onset error), policy success, user study
            assert tables.count() == 1 + 2 * 3 + 2
            assert images.count() == 4 + 1 + 1  # ... and the teachers' learning curves
            for k in range(images.count()):
                size = images.nth(k).evaluate("img => [img.complete, img.naturalWidth, img.naturalHeight]")
                assert size[0] and size[1] > 100 and size[2] > 100, (k, size)
            assert page.locator("ul.claims li").count() == 6 * 2 + 6
            assert page.locator("b.holds").count() >= 1
            assert [u for u in requests if not u.startswith(("file:", "data:"))] == []  # self-contained
            page.screenshot(path=str(tmp_path / "report.png"), full_page=True)
            assert (tmp_path / "report.png").stat().st_size > 10_000
        finally:
            browser.close()


def test_each_replayed_demonstration_gets_its_methods_contact_timelines_side_by_side() -> None:
    from touch2robot.report import ReportData, draw_figures, render_html, render_markdown

    t = np.linspace(0.0, 2.0, 41)
    rows = [
        {
            "source": source,
            "method": method,
            "task": task,
            "reference_id": demo,
            "t_ref": x,
            "region": region,
            "contact": bool(x > shift),
        }
        for task, demo in (("pick", "d1"), ("wipe", "d7"))
        for source, method, shift in (("human", "human", 0.5), ("real", "touch2robot", 0.6), ("real", "contrack", 1.5))
        for region in ("T1", "P1")
        for x in t
    ]
    comparison, policy, study = (
        SCHEMAS[t].empty_table().to_pandas() for t in ("comparison", "policy_eval", "user_study")
    )
    data = ReportData(comparison, policy, study, {"profile": "test"}, pd.DataFrame(rows))
    figures = draw_figures(data)
    assert set(figures) == {"timeline_pick_d1", "timeline_wipe_d7"} and all(
        len(png) > 10_000 for png in figures.values()
    )
    page = render_html(dataclasses.replace(data, figures=figures), "touch2robot")
    assert page.count("<img") == 2 and "Contact timelines: wipe, demonstration d7" in page
    assert "## Contact timelines: pick, demonstration d1" in render_markdown(data, "touch2robot")


def test_a_figure_pooled_over_fewer_seeds_than_the_sweep_says_so_in_its_cell() -> None:
    """A three-seed sweep where dexmachina's rotate results lack seed 2 and contrack's pick policy lacks seed 1:
    the report scores them on the seeds they have and says which are missing, cell by cell; the other cells
    say nothing."""
    from touch2robot.report import ReportData, pooled_policy, render_markdown

    skills = {"touch2robot": 0.8, "dexmachina": 0.5}
    clusters = pd.concat([comparison_clusters(skills, seed=s).assign(seed=s) for s in (0, 1, 2)], ignore_index=True)
    clusters = clusters[
        ~((clusters["method"] == "dexmachina") & (clusters["task"] == "rotate") & (clusters["seed"] == 2))
    ]
    comparison = comparison_table(clusters, versus="touch2robot", n_resamples=200, seeds=(0, 1, 2))
    policy = pd.concat([_policy_rows().assign(seed=s) for s in (0, 1, 2)], ignore_index=True)
    policy = policy[~((policy["method"] == "contrack") & (policy["task"] == "pick") & (policy["seed"] == 1))]
    study = SCHEMAS["user_study"].empty_table().to_pandas()
    text = render_markdown(ReportData(comparison, policy, study, {"profile": "test"}, seeds=(0, 1, 2)), "touch2robot")
    f1_rows = [line for line in text.splitlines() if line.startswith("| dexmachina |") and "(seed 2 missing)" in line]
    assert f1_rows, text  # the rotate cell
    assert not [line for line in text.splitlines() if line.startswith("| touch2robot |") and "missing" in line]
    (contrack_pick,) = [line for line in text.splitlines() if line.startswith("| pick | contrack |")]
    assert "4/20" in contrack_pick and "(seed 1 missing)" in contrack_pick and "| 0,2 |" in contrack_pick
    pooled = pooled_policy(policy, (0, 1, 2))
    (ours,) = pooled[(pooled["task"] == "pick") & (pooled["method"] == "touch2robot")].to_dict("records")
    low, high = wilson_interval(27, 30)  # touch2robot on pick: 9/10 in each of three seeds
    assert (ours["successes"], ours["episodes"]) == (27, 30)
    assert (ours["ci_low"], ours["ci_high"]) == pytest.approx((low, high))
