"""touch2robot.stats (Wilcoxon + Holm) against scipy/statsmodels, and the synthetic ratings."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats as sps
from statsmodels.stats.multitest import multipletests

from touch2robot.stats import CONDITIONS, QUESTIONS, holm, user_study
from touch2robot.synth.ratings import synthetic_ratings, write_ratings_csv


def _statsmodels_holm(p) -> np.ndarray:
    """statsmodels' Holm-adjusted p-values."""
    adjusted = multipletests(p, method="holm")[1]
    assert adjusted is not None  # its inferred return type admits None
    return adjusted


def _scipy_reference(ratings: pd.DataFrame) -> tuple[list[float], list[float]]:
    stats_, ps = [], []
    for q in QUESTIONS:
        w = ratings[ratings["question"] == q].pivot(index="participant", columns="condition", values="rating")
        res = sps.wilcoxon(
            w[CONDITIONS[0]].astype(float),
            w[CONDITIONS[1]].astype(float),
            zero_method="wilcox",
            method="asymptotic",
            correction=False,
        )
        stats_.append(float(res.statistic))  # pyright: ignore[reportAttributeAccessIssue]  scipy has no stubs
        ps.append(float(res.pvalue))  # pyright: ignore[reportAttributeAccessIssue]
    return stats_, ps


@pytest.mark.parametrize("seed", range(6))
def test_user_study_matches_scipy_and_statsmodels(seed: int) -> None:
    ratings = synthetic_ratings(10, seed=seed)
    res = user_study(ratings)
    frame = res.to_frame()
    assert frame["question"].tolist() == list(QUESTIONS)
    stat, p = _scipy_reference(ratings)
    np.testing.assert_allclose(frame["statistic"], stat, rtol=0, atol=0)
    np.testing.assert_allclose(frame["p"], p, rtol=1e-15)
    np.testing.assert_allclose(frame["p_holm"], _statsmodels_holm(p), rtol=1e-12)
    assert (frame["n"] == 10).all()
    assert (res.zero_method, res.method, res.correction) == ("wilcox", "asymptotic", False)
    assert "ties" in res.note.lower() and "zero" in res.note.lower()


def test_summary_columns() -> None:
    ratings = synthetic_ratings(10, seed=0)
    t = user_study(ratings).tests[0]
    q1 = ratings[ratings["question"] == "Q1"]
    vf = q1[q1["condition"] == "Visual Feedback"]["rating"].to_numpy()
    t2r = q1[q1["condition"] == "Touch2Robot"]["rating"].to_numpy()
    assert t.median_visual_feedback == np.median(vf)
    assert t.median_touch2robot == np.median(t2r)
    assert t.iqr_visual_feedback == pytest.approx(sps.iqr(vf))
    assert t.iqr_touch2robot == pytest.approx(sps.iqr(t2r))
    w = q1.pivot(index="participant", columns="condition", values="rating")
    assert t.n_zero == int((w[CONDITIONS[0]] == w[CONDITIONS[1]]).sum())


def test_all_zero_differences_give_nan_and_leave_the_holm_family() -> None:
    ratings = synthetic_ratings(10, seed=1)
    q2 = ratings["question"] == "Q2"
    vf = ratings[q2 & (ratings["condition"] == "Visual Feedback")].set_index("participant")["rating"]
    ratings.loc[q2 & (ratings["condition"] == "Touch2Robot"), "rating"] = (
        ratings.loc[q2 & (ratings["condition"] == "Touch2Robot"), "participant"].map(vf).to_numpy()
    )
    frame = user_study(ratings).to_frame().set_index("question")
    assert frame.loc[["Q2"], ["p", "p_holm"]].isna().all(axis=None)
    assert frame.loc["Q2", "statistic"] == 0.0 and frame.loc["Q2", "n_zero"] == 10
    others = frame.drop(index="Q2")
    np.testing.assert_allclose(others["p_holm"], _statsmodels_holm(others["p"]), rtol=1e-12)


# multipletests costs ~40 ms a call, so keep the example count modest.
@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0, 1, allow_nan=False), min_size=1, max_size=12))
def test_holm_matches_statsmodels(p: list[float]) -> None:
    np.testing.assert_allclose(holm(p), _statsmodels_holm(p), rtol=1e-12, atol=1e-15)


def test_holm_ignores_nan() -> None:
    out = holm([0.01, math.nan, 0.04])
    assert math.isnan(out[1])
    np.testing.assert_allclose(out[[0, 2]], _statsmodels_holm([0.01, 0.04]))
    assert np.isnan(holm([math.nan])).all() and holm([]).size == 0


def _ratings() -> pd.DataFrame:
    return synthetic_ratings(10, seed=0)


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (
            lambda d: d.drop(
                index=d.index[(d.participant == "P03") & (d.question == "Q2") & (d.condition == "Touch2Robot")]
            ),
            "participant 'P03' lacks one condition for question 'Q2'",
        ),
        (
            lambda d: d.assign(rating=d.rating.where(~((d.participant == "P05") & (d.question == "Q4")), 8)),
            r"participant 'P05', question 'Q4'.*not an integer in 1\.\.7",
        ),
        (
            lambda d: d.assign(rating=d.rating.where(~((d.participant == "P02") & (d.question == "Q1")), 0)),
            r"participant 'P02', question 'Q1'",
        ),
        (
            lambda d: d.assign(
                rating=d.rating.astype(float).where(~((d.participant == "P07") & (d.question == "Q3")), 4.5)
            ),
            r"participant 'P07', question 'Q3'.*4\.5",
        ),
        (
            lambda d: d.assign(
                rating=d.rating.astype(object).where(~((d.participant == "P01") & (d.question == "Q1")), "high")
            ),
            r"participant 'P01', question 'Q1'.*'high'",
        ),
        (lambda d: d[d.question != "Q3"], "missing question 'Q3'"),
        (
            lambda d: pd.concat([d, d[(d.participant == "P04") & (d.question == "Q1")].iloc[:1]]),
            "duplicate rows for participant 'P04', question 'Q1'",
        ),
        (lambda d: d.assign(condition=d.condition.replace("Touch2Robot", "Haptics")), "unknown condition 'Haptics'"),
        (lambda d: d.assign(question=d.question.replace("Q4", "Q9")), "unexpected question 'Q9'"),
        (lambda d: d.drop(columns="rating"), r"missing columns \['rating'\]"),
    ],
)
def test_validation_errors(mutate, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        user_study(mutate(_ratings()))


# --------------------------------------------------------------------------- synthetic ratings


def test_synthetic_ratings_are_plausible_and_labelled() -> None:
    df = synthetic_ratings()
    assert df.attrs["synthetic"] is True and df["synthetic"].all()
    assert df["participant"].nunique() == 10
    assert len(df) == 10 * len(QUESTIONS) * len(CONDITIONS)
    assert df["rating"].dtype == np.int64 and df["rating"].between(1, 7).all()
    w = df.pivot_table(index=["participant", "question"], columns="condition", values="rating")
    d = w["Touch2Robot"] - w["Visual Feedback"]
    assert d.mean() > 0
    assert (d == 0).any(), "zero differences (ties between conditions) expected"
    assert d.abs().duplicated().any(), "tied |differences| expected"
    pd.testing.assert_frame_equal(df, synthetic_ratings())
    assert not synthetic_ratings(seed=1).equals(df)
    assert synthetic_ratings(n_participants=12)["participant"].nunique() == 12
    with pytest.raises(ValueError, match="n_participants"):
        synthetic_ratings(0)


def test_write_ratings_csv_roundtrip_and_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write_ratings_csv(tmp_path / "study" / "ratings.csv")
    back = pd.read_csv(path)
    pd.testing.assert_frame_equal(back, synthetic_ratings(), check_dtype=False)
    user_study(back)
    assert [p.name for p in path.parent.iterdir()] == ["ratings.csv"]

    before = path.read_bytes()

    def boom(src: str, dst: str) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        write_ratings_csv(path, synthetic_ratings(seed=5))
    assert path.read_bytes() == before
    assert [p.name for p in path.parent.iterdir()] == ["ratings.csv"]
