"""The method comparison: intervals and paired tests that respect the data's structure.

Every contact score (precision, recall, F1, FPR) and the onset error is a ratio of sums: F1 =
2 TP / (2 TP + FP + FN) over all time-region samples, E = sum |t_eval - t_ref| / N over the
valid onset pairs. The samples of one demonstration are not independent (a contact lasts many
frames; a grasp that misses misses all of them), so the demonstration is the unit of every
interval and test here, and a score over several demonstrations pools their counts:

- **Interval of a score**: a 95 % percentile interval of a cluster bootstrap over
  demonstrations. Each of ``n_resamples`` resamples draws the n demonstrations with replacement
  (``rng.integers(0, n, (n_resamples, n))``) and recomputes the score from the summed counts of
  the demonstrations drawn: exactly ``scipy.stats.bootstrap(counts, paired=True,
  method="percentile")`` with each demonstration's counts as one paired observation. Percentile
  rather than BCa: BCa's jackknife acceleration is undefined when leaving one demonstration out
  leaves a score undefined (no contact left), and the percentile interval stays in the score's
  range. A resample whose score is undefined (0/0) carries no score and is left out.
- **Paired difference** (``versus`` - method, e.g. Touch2Robot - a baseline): on the
  demonstrations both were scored on only, with the same resampled demonstrations for both, so
  the interval is that of the difference, not of two independent scores.
- **Paired test**: the two-sided Wilcoxon signed-rank test over demonstrations of the
  per-demonstration scores, ``scipy.stats.wilcoxon(d, zero_method="wilcox", correction=False,
  alternative="two-sided", method="auto")`` with d = versus - method on the demonstrations
  where both scores are defined. "auto" is SciPy's documented rule: the exact null distribution
  for n <= 50 distinct non-zero differences, exhaustive sign flips for n <= 13 with ties or
  zeros, the normal approximation otherwise; all three are deterministic. Fewer than one
  non-zero difference: p is NaN.
- **Student ablations** (no tactile, no geometry, no dropout: a ``variant`` of a method) are compared
  with their own full model the same way, on the held-out demonstrations both reconstructed.
- **Multiple comparisons**: the p-values of the methods (or ablations) compared on one metric,
  source and task form one family, Holm-adjusted (:func:`touch2robot.stats.holm`).
- **Success rates**: Wilson score intervals (:func:`wilson_interval`).
- **Seeds**: a sweep's seeds (``seed`` column) pool into each demonstration: its counts are summed over
  the seeds, so the demonstration stays the unit and the seeds' spread enters the interval through the
  pooled counts. Each row names the seeds pooled into it (``seeds``) and those of the sweep it has no
  results of (``seeds_missing``): a cell that lacks a seed is scored on the ones it has, and says so.

The random draws of one cell (source, task, method) come from a generator seeded by the
comparison's seed and the cell's name, so a cell's interval does not change when other cells
are added or removed. No Prefect imports: the evaluate flow wraps :func:`comparison_table`.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from schemas.tables import SCHEMAS
from touch2robot.metrics import ALL
from touch2robot.stats import holm

__all__ = [
    "CLUSTER_COLUMNS",
    "METRICS",
    "Interval",
    "cluster_weights",
    "comparison_table",
    "paired_wilcoxon",
    "ratio_interval",
    "wilson_interval",
]

Z_95 = 1.959963984540054

# Per-demonstration sums a score is computed from (the cluster table's value columns).
CLUSTER_COLUMNS: tuple[str, ...] = ("tp", "fp", "fn", "tn", "onset_error_sum_ms", "onset_pairs")

# Each metric as numerator / denominator, both linear in CLUSTER_COLUMNS (coefficients in that order).
METRICS: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "precision": ((1, 0, 0, 0, 0, 0), (1, 1, 0, 0, 0, 0)),
    "recall": ((1, 0, 0, 0, 0, 0), (1, 0, 1, 0, 0, 0)),
    "f1": ((2, 0, 0, 0, 0, 0), (2, 1, 1, 0, 0, 0)),
    "fpr": ((0, 1, 0, 0, 0, 0), (0, 1, 0, 1, 0, 0)),
    "onset_error_ms": ((0, 0, 0, 0, 1, 0), (0, 0, 0, 0, 0, 1)),
}


def wilson_interval(successes: int, n: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default); (0, 1) when n = 0."""
    if n <= 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def cluster_weights(n: int, n_resamples: int, rng: np.random.Generator) -> np.ndarray:
    """(n_resamples, n) counts: how often each of n clusters is drawn in each bootstrap resample
    (the draws of ``scipy.stats.bootstrap``: ``rng.integers(0, n, (n_resamples, n))``)."""
    drawn = rng.integers(0, n, (n_resamples, n))
    flat = (np.arange(n_resamples)[:, None] * n + drawn).ravel()
    return np.bincount(flat, minlength=n_resamples * n).reshape(n_resamples, n).astype(np.float64)


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    out = np.full(np.broadcast(num, den).shape, np.nan)
    np.divide(num, den, out=out, where=den != 0)
    return out


@dataclass(frozen=True, slots=True)
class Interval:
    """A point estimate with its percentile bootstrap interval (NaN where undefined)."""

    estimate: float
    low: float
    high: float


def _percentile(resampled: np.ndarray, estimate: float, confidence: float) -> Interval:
    finite = resampled[np.isfinite(resampled)]
    if not np.isfinite(estimate) or finite.size == 0:
        return Interval(estimate, math.nan, math.nan)
    alpha = (1.0 - confidence) / 2
    low, high = np.percentile(finite, [100 * alpha, 100 * (1 - alpha)])
    return Interval(float(estimate), float(low), float(high))


def ratio_interval(num: np.ndarray, den: np.ndarray, weights: np.ndarray, confidence: float = 0.95) -> Interval:
    """sum(num) / sum(den) over the clusters, with its percentile interval over the resamples
    ``weights`` (from :func:`cluster_weights`)."""
    num, den = np.asarray(num, np.float64), np.asarray(den, np.float64)
    estimate = float(_ratio(num.sum(), den.sum()))
    return _percentile(_ratio(weights @ num, weights @ den), estimate, confidence)


def difference_interval(
    a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], weights: np.ndarray, confidence: float = 0.95
) -> Interval:
    """ratio(a) - ratio(b) on the same clusters, each resample drawing the same clusters for both."""
    (na, da), (nb, db) = ((np.asarray(x, np.float64), np.asarray(y, np.float64)) for x, y in (a, b))
    estimate = float(_ratio(na.sum(), da.sum()) - _ratio(nb.sum(), db.sum()))
    resampled = _ratio(weights @ na, weights @ da) - _ratio(weights @ nb, weights @ db)
    return _percentile(resampled, estimate, confidence)


@dataclass(frozen=True, slots=True)
class PairedTest:
    """Wilcoxon signed-rank test over clusters: n = the pairs where both scores are defined."""

    statistic: float
    p_value: float
    n: int


def paired_wilcoxon(a: np.ndarray, b: np.ndarray) -> PairedTest:
    """Two-sided Wilcoxon signed-rank test of per-cluster scores a vs b (the call in the module's docstring)."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    d = d[np.isfinite(d)]
    if not np.any(d != 0):
        return PairedTest(math.nan, math.nan, int(d.size))
    from scipy import stats  # here, not at import: 0.7 s of every command's start

    result = stats.wilcoxon(d, zero_method="wilcox", correction=False, alternative="two-sided", method="auto")
    return PairedTest(float(result.statistic), float(result.pvalue), int(d.size))  # pyright: ignore[reportAttributeAccessIssue]


def _rng(seed: int, *cell: str) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32("/".join(cell).encode())])


def _sums(frame: pd.DataFrame, coefficients: tuple[float, ...]) -> np.ndarray:
    return frame[list(CLUSTER_COLUMNS)].to_numpy(np.float64) @ np.asarray(coefficients, np.float64)


def _cell_rows(
    clusters: pd.DataFrame, keys: dict, versus: str, confidence: float, n_resamples: int, seed: int
) -> list[dict]:
    """Rows of one (reference_source, source, task) cell: every method's (and ablation's) scores and, for
    each method other than ``versus``, its paired comparison with ``versus``; an ablation is compared with
    its own method's full model."""
    by_entry = {
        (str(m), str(v)): g.set_index("demonstration").sort_index()
        for (m, v), g in clusters.groupby(["method", "variant"], sort=True)
    }
    rows = []
    cell = (str(keys["reference_source"]), str(keys["source"]), str(keys["task"]))
    for (method, variant), own in by_entry.items():
        weights = cluster_weights(len(own), n_resamples, _rng(seed, *cell, method, *([variant] if variant else [])))
        against = (method, "") if variant else (versus, "")
        paired = None
        if (method, variant) != against and against in by_entry:
            common = own.index.intersection(by_entry[against].index)
            if len(common):
                mine, theirs = own.loc[common], by_entry[against].loc[common]
                stream = _rng(seed, *cell, method, *([variant] if variant else []), against[0])
                paired = (mine, theirs, cluster_weights(len(common), n_resamples, stream))
        for metric, (num_c, den_c) in METRICS.items():
            num, den = _sums(own, num_c), _sums(own, den_c)
            score = ratio_interval(num, den, weights, confidence)
            row = {
                **keys,
                "metric": metric,
                "method": method,
                "variant": variant,
                "estimate": score.estimate,
                "ci_low": score.low,
                "ci_high": score.high,
                "n_demonstrations": len(own),
                "versus": None,
                "difference": math.nan,
                "difference_ci_low": math.nan,
                "difference_ci_high": math.nan,
                "n_paired": 0,
                "wilcoxon_statistic": math.nan,
                "p_value": math.nan,
                "confidence": confidence,
                "n_resamples": n_resamples,
            }
            if paired is not None:
                mine, theirs, pair_weights = paired
                a = (_sums(theirs, num_c), _sums(theirs, den_c))
                b = (_sums(mine, num_c), _sums(mine, den_c))
                diff = difference_interval(a, b, pair_weights, confidence)
                test = paired_wilcoxon(_ratio(*a), _ratio(*b))
                row |= {
                    "versus": against[0],
                    "difference": diff.estimate,
                    "difference_ci_low": diff.low,
                    "difference_ci_high": diff.high,
                    "n_paired": test.n,
                    "wilcoxon_statistic": test.statistic,
                    "p_value": test.p_value,
                }
            rows.append(row)
    return rows


def comparison_table(
    clusters: pd.DataFrame,
    versus: str,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int = 0,
    seeds: tuple[int, ...] | None = None,
) -> pd.DataFrame:
    """Rows of the ``comparison`` table from per-demonstration sums.

    Args:
        clusters: one row per (reference_source, source, method, task, demonstration) with the sums
            of :data:`CLUSTER_COLUMNS` over that demonstration's samples (regions pooled); an optional
            ``variant`` column names a student ablation of the method ('' = the method itself), an
            optional ``seed`` column the sweep seed (absent: seed 0), pooled per demonstration.
        versus: the method every other method is compared with (paired, per cell).
        confidence: the intervals' coverage.
        n_resamples: bootstrap resamples per interval.
        seed: the comparison's seed (each cell draws from its own generator, see the module docstring).
        seeds: the sweep's seeds, against which each row's ``seeds_missing`` is reported (default: the
            seeds found in ``clusters``).

    Returns:
        Columns as ``schemas.tables.comparison``: per (reference_source, source, task incl. '*', method,
        metric) the score and interval and, for methods other than ``versus``, the paired difference
        versus - method, its interval, the Wilcoxon test and the Holm-adjusted p over the methods
        compared in that (reference_source, source, task, metric).
    """
    names = SCHEMAS["comparison"].names
    needed = ["reference_source", "source", "method", "task", "demonstration", *CLUSTER_COLUMNS]
    missing = [c for c in needed if c not in clusters.columns]
    if missing:
        raise ValueError(f"comparison clusters are missing columns {missing}")
    # no variant (a missing column, or NULL) = the method itself; grouping would drop a NULL key
    variant = clusters["variant"].fillna("") if "variant" in clusters.columns else ""
    of_seed = clusters["seed"].fillna(0).astype(np.int64) if "seed" in clusters.columns else 0
    clusters = clusters.assign(variant=variant, seed=of_seed)
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    if clusters.empty:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in names})
    cell = ["reference_source", "source", "method", "variant", "task"]
    duplicated = clusters.duplicated([*cell, "demonstration", "seed"])
    if duplicated.any():
        first = clusters[duplicated].iloc[0]
        raise ValueError(f"comparison clusters: demonstration {first['demonstration']!r} appears twice in one cell")
    swept = tuple(sorted(set(clusters["seed"]))) if seeds is None else tuple(seeds)
    coverage = _seed_coverage(clusters, cell, swept)
    clusters = clusters.groupby([*cell, "demonstration"], as_index=False, sort=True)[list(CLUSTER_COLUMNS)].sum()
    rows: list[dict] = []
    for (reference, source), group in clusters.groupby(["reference_source", "source"], sort=True):
        pooled = group.groupby(["method", "variant", "demonstration"], as_index=False)[list(CLUSTER_COLUMNS)].sum()
        cells = [(task, g) for task, g in group.groupby("task", sort=True)] + [(ALL, pooled)]
        for task, g in cells:
            keys = {"reference_source": reference, "source": source, "task": task}
            rows += _cell_rows(g, keys, versus, confidence, n_resamples, seed)
    table = pd.DataFrame(rows)
    family = ["reference_source", "source", "task", "metric"]
    table["p_holm"] = table.groupby(family, sort=False)["p_value"].transform(lambda p: holm(p.to_numpy()))
    table = table.drop(columns=["seeds", "seeds_missing"], errors="ignore").merge(coverage, on=cell, how="left")
    order = ["reference_source", "source", "metric", "task", "method", "variant"]
    return table.sort_values(order, ignore_index=True)[names]


def _seed_coverage(clusters: pd.DataFrame, cell: list[str], swept: tuple[int, ...]) -> pd.DataFrame:
    """Per cell (and per method over all tasks): the seeds it has results of and the swept ones it lacks."""
    per_task = clusters.groupby(cell, sort=False)["seed"].agg(lambda s: frozenset(s.tolist())).reset_index()
    overall = per_task.groupby([c for c in cell if c != "task"], as_index=False)["seed"].agg(
        lambda sets: frozenset().union(*sets)
    )
    coverage = pd.concat([per_task, overall.assign(task=ALL)], ignore_index=True)

    def spelled(values: Iterable[int]) -> str:
        return ",".join(str(v) for v in sorted(values))

    return coverage.assign(
        seeds=coverage["seed"].map(spelled),
        seeds_missing=coverage["seed"].map(lambda have: spelled(set(swept) - have)),
    ).drop(columns="seed")
