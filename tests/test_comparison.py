"""The comparison's statistics against independent implementations on fixed data: SciPy's bootstrap
on the same clusters, an exhaustive signed-rank null distribution, statsmodels' Wilson interval and
Holm correction."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pandas as pd
import pytest
from conftest import comparison_clusters
from scipy import stats
from statsmodels.stats.multitest import multipletests
from statsmodels.stats.proportion import proportion_confint

from schemas.tables import SCHEMAS
from touch2robot.comparison.statistics import (
    CLUSTER_COLUMNS,
    cluster_weights,
    comparison_table,
    difference_interval,
    paired_wilcoxon,
    ratio_interval,
    wilson_interval,
)
from touch2robot.metrics import ALL


def _counts(seed: int, n: int) -> np.ndarray:
    """(n, 4) tp, fp, fn, tn of n demonstrations of uneven length."""
    rng = np.random.default_rng(seed)
    return rng.integers(0, 60, (n, 4)) + rng.integers(0, 2, (n, 1)) * 40


def _f1(tp, fp, fn, axis=-1):
    return 2 * tp.sum(axis) / (2 * tp.sum(axis) + fp.sum(axis) + fn.sum(axis))


@pytest.mark.parametrize("n", [7, 30])
def test_the_interval_of_a_pooled_score_is_scipys_paired_percentile_bootstrap(n: int) -> None:
    counts = _counts(n, n)
    tp, fp, fn = counts[:, 0], counts[:, 1], counts[:, 2]
    mine = ratio_interval(2 * tp, 2 * tp + fp + fn, cluster_weights(n, 4000, np.random.default_rng(5)))
    theirs = stats.bootstrap(
        (tp, fp, fn), _f1, paired=True, vectorized=True, n_resamples=4000, method="percentile", rng=5
    )
    assert mine.estimate == pytest.approx(_f1(tp, fp, fn))
    assert (mine.low, mine.high) == pytest.approx(tuple(theirs.confidence_interval), abs=1e-12)


def test_a_paired_difference_resamples_the_same_demonstrations_for_both_methods() -> None:
    n = 12
    a, b = _counts(1, n), _counts(2, n)
    mine = difference_interval(
        (2 * a[:, 0], 2 * a[:, 0] + a[:, 1] + a[:, 2]),
        (2 * b[:, 0], 2 * b[:, 0] + b[:, 1] + b[:, 2]),
        cluster_weights(n, 3000, np.random.default_rng(9)),
    )

    def difference(atp, afp, afn, btp, bfp, bfn, axis=-1):
        return _f1(atp, afp, afn, axis) - _f1(btp, bfp, bfn, axis)

    columns = (a[:, 0], a[:, 1], a[:, 2], b[:, 0], b[:, 1], b[:, 2])
    theirs = stats.bootstrap(columns, difference, paired=True, n_resamples=3000, method="percentile", rng=9)
    assert mine.estimate == pytest.approx(difference(*columns))
    assert (mine.low, mine.high) == pytest.approx(tuple(theirs.confidence_interval), abs=1e-12)


def test_the_cluster_interval_is_wider_than_a_sample_level_one_when_demonstrations_hit_or_miss_whole() -> None:
    """Samples of one demonstration share its outcome: resampling samples as if independent would
    claim a precision the data does not have."""
    rng = np.random.default_rng(0)
    hits = rng.random(20) < 0.5  # each demonstration all hit or all missed, 50 samples each
    tp, fn = np.where(hits, 50, 0), np.where(hits, 0, 50)
    clustered = ratio_interval(tp, tp + fn, cluster_weights(20, 4000, rng))
    samples = np.repeat(hits, 50).astype(float)
    flat = ratio_interval(samples, np.ones_like(samples), cluster_weights(samples.size, 4000, rng))
    assert clustered.high - clustered.low > 3 * (flat.high - flat.low)


def _exact_signed_rank_p(d: np.ndarray) -> float:
    """Two-sided p of the signed-rank statistic by enumerating all 2^n sign patterns (distinct |d|)."""
    ranks = stats.rankdata(np.abs(d))
    observed = ranks[d > 0].sum()
    total = ranks.sum()
    t_obs = min(observed, total - observed)
    sums = np.array([np.dot(signs, ranks) for signs in itertools.product((0, 1), repeat=d.size)])
    return min(1.0, 2 * np.mean(sums <= t_obs))


def test_the_paired_test_is_the_exact_signed_rank_test_for_few_distinct_differences() -> None:
    rng = np.random.default_rng(3)
    a = rng.random(11)
    b = a - rng.normal(0.08, 0.1, 11)
    b[[2, 7]] = np.nan  # undefined per-demonstration scores leave the test
    test = paired_wilcoxon(a, b)
    d = (a - b)[np.isfinite(b)]
    assert test.n == 9
    assert test.p_value == pytest.approx(_exact_signed_rank_p(d), rel=1e-12)
    assert paired_wilcoxon(a, a).p_value != paired_wilcoxon(a, a).p_value  # no difference: NaN


@pytest.mark.parametrize(("k", "n"), [(0, 10), (3, 10), (10, 10), (17, 50), (1, 1)])
def test_wilson_interval_matches_statsmodels(k: int, n: int) -> None:
    theirs = np.asarray(proportion_confint(k, n, method="wilson"), dtype=np.float64)
    assert wilson_interval(k, n) == pytest.approx(tuple(theirs), abs=1e-12)


def _clusters() -> pd.DataFrame:
    """Three methods on the same demonstrations of two tasks; 'c' scores only half of them."""
    return comparison_clusters({"a": 0.8, "b": 0.6, "c": 0.7}, seed=11, scores=lambda m, k: m != "c" or k % 2 == 0)


def test_the_comparison_table_pools_demonstrations_pairs_them_and_holm_corrects_each_family() -> None:
    clusters = _clusters()
    table = comparison_table(clusters, versus="a", n_resamples=2000, seed=1)
    assert list(table.columns) == SCHEMAS["comparison"].names
    f1 = table[table["metric"] == "f1"].set_index(["task", "method"])
    for row in f1.reset_index().to_dict("records"):
        task, method = row["task"], row["method"]
        mine = clusters[(clusters["method"] == method) & ((clusters["task"] == task) | (task == ALL))]
        assert row["estimate"] == pytest.approx(_f1(mine["tp"], mine["fp"], mine["fn"], axis=0))
        assert row["ci_low"] <= row["estimate"] <= row["ci_high"]
        assert row["n_demonstrations"] == len(mine)
    assert f1.loc[(ALL, "a"), "versus"] is None and math.isnan(float(f1.loc[(ALL, "a"), "p_value"]))  # pyright: ignore[reportArgumentType]
    # c is compared on the demonstrations both scored: its own ten of twenty
    assert f1.loc[(ALL, "c"), "n_paired"] == 10 and f1.loc[(ALL, "b"), "n_paired"] == 20
    both = clusters[clusters["demonstration"].isin(clusters.loc[clusters["method"] == "c", "demonstration"])]
    a, c = (both[both["method"] == m] for m in ("a", "c"))
    expected = _f1(a["tp"], a["fp"], a["fn"], axis=0) - _f1(c["tp"], c["fp"], c["fn"], axis=0)
    assert f1.loc[(ALL, "c"), "difference"] == pytest.approx(expected)
    for (task, metric), family in table[table["versus"].notna()].groupby(["task", "metric"]):
        assert family["p_holm"].to_numpy() == pytest.approx(
            multipletests(family["p_value"].to_numpy(), method="holm")[1]
        ), (task, metric)
    onset = table[(table["metric"] == "onset_error_ms") & (table["task"] == "pick") & (table["method"] == "b")]
    mine = clusters[(clusters["task"] == "pick") & (clusters["method"] == "b")]
    assert onset["estimate"].item() == pytest.approx(mine["onset_error_sum_ms"].sum() / mine["onset_pairs"].sum())


def test_a_cells_interval_does_not_depend_on_the_other_cells() -> None:
    clusters = _clusters()
    whole = comparison_table(clusters, versus="a", n_resamples=500, seed=4)
    alone = comparison_table(clusters[clusters["method"] == "b"], versus="a", n_resamples=500, seed=4)
    keys = ["reference_source", "source", "metric", "task", "method"]
    merged = alone.merge(whole, on=keys, suffixes=("", "_whole"))
    assert len(merged) == len(alone)
    np.testing.assert_array_equal(merged["ci_low"], merged["ci_low_whole"])


def test_bad_clusters_are_refused_with_the_reason() -> None:
    clusters = _clusters()
    with pytest.raises(ValueError, match="missing columns"):
        comparison_table(clusters.drop(columns="tn"), versus="a")
    with pytest.raises(ValueError, match="appears twice"):
        comparison_table(pd.concat([clusters, clusters.iloc[:1]]), versus="a")
    with pytest.raises(ValueError, match="confidence"):
        comparison_table(clusters, versus="a", confidence=1.5)
    assert comparison_table(clusters.iloc[:0], versus="a").empty
    assert set(CLUSTER_COLUMNS) <= set(clusters.columns)


def test_the_commands_closing_table_gives_each_methods_f1_with_its_interval_and_paired_difference() -> None:
    from flows.pipeline import headline

    table = comparison_table(_clusters(), versus="a", n_resamples=500, seed=2)
    rows = pd.DataFrame(table).replace({np.nan: None}).to_dict("records")
    overall = [r for r in rows if r["task"] == ALL and r["metric"] == "f1"]
    lines = dict(headline({"evaluate": {"f1_compared": overall, "f1": {"sim/a": 0.5}}}))
    line = " ".join(figures for stage, figures in headline({"evaluate": {"f1_compared": overall}}))
    a, b = (next(r for r in overall if r["method"] == m) for m in ("a", "b"))
    assert f"a F1 {a['estimate']:.3f} [{a['ci_low']:.3f}, {a['ci_high']:.3f}]" in line
    assert f"b F1 {b['estimate']:.3f}" in line and f"(a - it: {b['difference']:+.3f} [" in line
    assert f"n {b['n_paired']})" in line and "evaluate" not in lines  # the bare F1 line only without a comparison
    undefined = {**b, "estimate": None, "ci_low": None, "ci_high": None, "p_holm": None}
    assert "b F1 n/a [n/a, n/a]" in dict(headline({"evaluate": {"f1_compared": [undefined]}}))["evaluate: sim vs human"]
    assert [stage for stage, _ in headline({"evaluate": {"f1_compared": overall}})] == [
        "evaluate: sim vs human",
        "",
        "",
    ]


def test_a_student_ablation_is_compared_with_its_full_model_on_the_same_demonstrations() -> None:
    from touch2robot.report import claims

    clusters = _clusters()
    reconstructed = clusters[clusters["method"] == "a"].assign(source="reconstructed", method="touch2robot")
    ablation = reconstructed.assign(variant="no_tactile", tp=reconstructed["tp"] // 2)
    table = comparison_table(pd.concat([clusters, reconstructed, ablation]), versus="a", n_resamples=500)
    rows = table[(table["source"] == "reconstructed") & (table["metric"] == "f1") & (table["task"] == ALL)]
    full, cut = (rows[rows["variant"] == v].iloc[0] for v in ("", "no_tactile"))
    assert full["versus"] is None and cut["versus"] == "touch2robot" and cut["n_paired"] == 20
    assert cut["difference"] == pytest.approx(full["estimate"] - cut["estimate"]) and cut["difference_ci_low"] > 0
    # the methods' own rows are untouched by the ablation's presence
    alone = comparison_table(clusters, versus="a", n_resamples=500)
    pd.testing.assert_frame_equal(table[table["source"] == "sim"].reset_index(drop=True), alone)
    stated = [c for c in claims(table, pd.DataFrame(columns=["task", "method"]), "a") if "ablation" in c.statement]
    assert [c.verdict for c in stated if " F1 " in c.statement] == ["holds"]
    assert stated[0].statement.startswith("touch2robot's full student has a higher F1 than its no_tactile ablation")


def test_seeds_pool_into_each_demonstration_and_a_cell_says_which_seeds_it_lacks() -> None:
    """Three seeds of two methods; dexmachina lacks seed 2 on rotate. A demonstration's counts are summed over
    the seeds it has (so its scores are those of the pooled counts), and every row names its seeds."""
    skills = {"touch2robot": 0.8, "dexmachina": 0.5}
    by_seed = [comparison_clusters(skills, seed=s).assign(seed=s) for s in (0, 1, 2)]
    clusters = pd.concat(by_seed, ignore_index=True)
    lacking = (clusters["method"] == "dexmachina") & (clusters["task"] == "rotate") & (clusters["seed"] == 2)
    clusters = clusters[~lacking]
    table = comparison_table(clusters, versus="touch2robot", n_resamples=200, seeds=(0, 1, 2))
    f1 = table[table["metric"] == "f1"].set_index(["method", "task"])
    assert f1.loc[("touch2robot", ALL), "seeds"] == "0,1,2" and f1.loc[("touch2robot", ALL), "seeds_missing"] == ""
    assert (
        f1.loc[("dexmachina", "rotate"), "seeds"] == "0,1" and f1.loc[("dexmachina", "rotate"), "seeds_missing"] == "2"
    )
    assert f1.loc[("dexmachina", "pick"), "seeds_missing"] == ""
    assert f1.loc[("dexmachina", ALL), "seeds"] == "0,1,2"  # over all tasks it has every seed somewhere
    pooled = clusters[clusters["method"] == "touch2robot"][["tp", "fp", "fn"]].sum()
    assert f1.loc[("touch2robot", ALL), "estimate"] == pytest.approx(
        2 * pooled["tp"] / (2 * pooled["tp"] + pooled["fp"] + pooled["fn"])
    )
    assert f1.loc[("touch2robot", ALL), "n_demonstrations"] == 20  # demonstrations, not demonstrations x seeds
    # a seed the sweep asked for and nobody has is missing everywhere
    wider = comparison_table(clusters, versus="touch2robot", n_resamples=200, seeds=(0, 1, 2, 3))
    assert set(wider.loc[wider["method"] == "touch2robot", "seeds_missing"]) == {"3"}
