"""User-study statistics: paired Wilcoxon signed-rank tests per question with Holm correction.

Ratings arrive in long form, one row per (participant, condition, question) with an integer
rating on a 1..7 Likert scale. For every question the ratings of "Visual Feedback" and
"Touch2Robot" are paired by participant and compared with ``scipy.stats.wilcoxon`` (two-sided,
on the original ratings, d = Visual Feedback - Touch2Robot); the per-question p-values are then
Holm-adjusted across the questions (family-wise error control).

Why an explicit normal approximation: Likert differences of ten participants are full of ties
and zero differences, so the exact signed-rank distribution (which assumes distinct, non-zero
differences) does not apply. SciPy 1.18 documents ``method`` in {"auto", "exact", "asymptotic"}
or a ``PermutationMethod``; the old name "approx" is still accepted but only as an undocumented
alias that ``wilcoxon`` rewrites to "asymptotic". Left on "auto" it would silently
switch to an exhaustive sign-flip permutation test for n <= 13 when ties or zeros occur, and
"exact" with ties rounds the statistic onto the no-ties distribution. We therefore always pass
``method="asymptotic"`` (normal approximation with the tie-corrected variance) and
``zero_method="wilcox"`` (zero differences are discarded before ranking, the classical
convention, so the effective n is the number of non-zero differences), ``correction=False``
(SciPy's default) -- the exact same call anyone can re-run with scipy. When every difference of
a question is zero the test is undefined: statistic 0, p NaN, and that question is left out of
the Holm family (its adjusted p is NaN as well).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

__all__ = [
    "CONDITIONS",
    "QUESTIONS",
    "QuestionTest",
    "UserStudyResult",
    "holm",
    "user_study",
]

CONDITIONS: tuple[str, str] = ("Visual Feedback", "Touch2Robot")
QUESTIONS: tuple[str, ...] = ("Q1", "Q2", "Q3", "Q4")
RATING_MIN, RATING_MAX = 1, 7

ZERO_METHOD = "wilcox"
METHOD = "asymptotic"
CORRECTION = False
TIES_NOTE = (
    "Ties and zero differences make the exact signed-rank distribution invalid, so p-values use "
    "scipy.stats.wilcoxon(method='asymptotic', zero_method='wilcox', correction=False): zero "
    "differences are dropped before ranking and the normal approximation uses the tie-corrected "
    "variance. A question whose differences are all zero has p = NaN and is left out of the Holm "
    "family."
)


def holm(pvalues: Sequence[float]) -> np.ndarray:
    """Holm step-down adjusted p-values (same as statsmodels ``multipletests(method="holm")``).

    Sort the m p-values ascending, multiply the k-th smallest (k = 0..m-1) by (m - k), take the
    running maximum and cap at 1. NaN p-values are not tests: they are excluded from the family
    (m counts only defined p-values) and stay NaN.
    """
    p = np.asarray(pvalues, dtype=np.float64)
    out = np.full(p.shape, np.nan)
    defined = np.flatnonzero(~np.isnan(p))
    m = defined.size
    if m == 0:
        return out
    order = defined[np.argsort(p[defined], kind="stable")]
    scaled = (m - np.arange(m)) * p[order]
    out[order] = np.minimum(np.maximum.accumulate(scaled), 1.0)
    return out


@dataclass(frozen=True, slots=True)
class QuestionTest:
    """Wilcoxon signed-rank result for one question.

    ``median_*``/``iqr_*`` summarise each condition's ratings (IQR = Q3 - Q1, numpy's linear
    quantiles); ``n_zero`` differences are discarded by ``zero_method="wilcox"``; ``statistic``
    is scipy's two-sided statistic min(R+, R-); ``p_holm`` is Holm-adjusted across questions.
    """

    question: str
    n: int
    n_zero: int
    median_visual_feedback: float
    iqr_visual_feedback: float
    median_touch2robot: float
    iqr_touch2robot: float
    statistic: float
    p: float
    p_holm: float


@dataclass(frozen=True, slots=True)
class UserStudyResult:
    """Per-question tests plus the exact scipy settings used to obtain them."""

    tests: tuple[QuestionTest, ...]
    zero_method: str = ZERO_METHOD
    method: str = METHOD
    correction: bool = CORRECTION
    note: str = field(default=TIES_NOTE, repr=False)

    def to_frame(self) -> pd.DataFrame:
        """One row per question (columns as :class:`QuestionTest`)."""
        return pd.DataFrame([asdict(t) for t in self.tests])


def _validate(ratings: pd.DataFrame, questions: Sequence[str]) -> pd.DataFrame:
    needed = ["participant", "condition", "question", "rating"]
    missing_cols = [c for c in needed if c not in ratings.columns]
    if missing_cols:
        raise ValueError(f"ratings is missing columns {missing_cols}")
    df = ratings[needed]
    for col in ("participant", "condition", "question"):
        if df[col].isna().any():
            raise ValueError(f"ratings has an empty {col!r} value")

    bad_cond = sorted(set(df["condition"]) - set(CONDITIONS))
    if bad_cond:
        raise ValueError(f"unknown condition {bad_cond[0]!r}; expected one of {list(CONDITIONS)}")
    unknown_q = sorted(set(df["question"]) - set(questions))
    if unknown_q:
        raise ValueError(f"unexpected question {unknown_q[0]!r}; expected {list(questions)}")
    absent_q = [q for q in questions if q not in set(df["question"])]
    if absent_q:
        raise ValueError(f"missing question {absent_q[0]!r}: no ratings for it")

    values = pd.to_numeric(df["rating"], errors="coerce").to_numpy(dtype=np.float64)
    bad = ~(np.isfinite(values) & (values == np.round(values)))
    bad |= (values < RATING_MIN) | (values > RATING_MAX)
    if bad.any():
        row = df[bad].iloc[0]
        raise ValueError(
            f"participant {row['participant']!r}, question {row['question']!r}, condition "
            f"{row['condition']!r}: rating {row['rating']!r} is not an integer in "
            f"{RATING_MIN}..{RATING_MAX}"
        )
    df = df.assign(rating=values.astype(np.int64))

    dup = df.duplicated(["participant", "condition", "question"], keep=False)
    if dup.any():
        row = df[dup].iloc[0]
        raise ValueError(
            f"duplicate rows for participant {row['participant']!r}, question "
            f"{row['question']!r}, condition {row['condition']!r}"
        )

    per_pq = df.groupby(["question", "participant"])["condition"].nunique()
    unpaired = per_pq[per_pq < len(CONDITIONS)]
    if len(unpaired):
        question, participant = unpaired.index[0]
        raise ValueError(
            f"participant {participant!r} lacks one condition for question {question!r}: ratings must be paired"
        )
    return df


def _iqr(x: np.ndarray) -> float:
    q1, q3 = np.percentile(x, [25, 75])
    return float(q3 - q1)


def user_study(ratings: pd.DataFrame, questions: Sequence[str] = QUESTIONS) -> UserStudyResult:
    """Paired two-sided Wilcoxon signed-rank test per question, Holm-corrected across questions.

    Args:
        ratings: long form with columns participant, condition ("Visual Feedback" or
            "Touch2Robot"), question and rating (integer 1..7); other columns (e.g.
            ``synthetic``) are ignored.
        questions: the questions that must all be present (and nothing else).

    Returns:
        :class:`UserStudyResult` with one :class:`QuestionTest` per question, in ``questions``
        order, computed with ``scipy.stats.wilcoxon(vf, t2r, zero_method="wilcox",
        method="asymptotic", correction=False)`` (see the module docstring for why).

    Raises:
        ValueError: naming the participant/question for unpaired ratings, ratings outside 1..7
            or non-integer, duplicate rows; naming the question for missing or unexpected
            questions; unknown conditions or missing columns.
    """
    df = _validate(ratings, questions)
    raw = []
    for q in questions:
        wide = df[df["question"] == q].pivot(index="participant", columns="condition", values="rating")
        vf = wide[CONDITIONS[0]].to_numpy(dtype=np.float64)
        t2r = wide[CONDITIONS[1]].to_numpy(dtype=np.float64)
        d = vf - t2r
        if np.all(d == 0):
            # scipy returns NaN here too (with a warning); the test has no information.
            statistic, p = 0.0, float("nan")
        else:
            from scipy import stats  # here, not at import: 0.7 s of every command's start

            res = stats.wilcoxon(vf, t2r, zero_method=ZERO_METHOD, method=METHOD, correction=CORRECTION)
            # scipy ships no stubs: its result bunch reads as an unnamed class to the checker
            statistic, p = float(res.statistic), float(res.pvalue)  # pyright: ignore[reportAttributeAccessIssue]
        raw.append((q, vf, t2r, int(np.count_nonzero(d == 0)), statistic, p))
    adjusted = holm([r[5] for r in raw])
    tests = tuple(
        QuestionTest(
            question=q,
            n=int(vf.size),
            n_zero=n_zero,
            median_visual_feedback=float(np.median(vf)),
            iqr_visual_feedback=_iqr(vf),
            median_touch2robot=float(np.median(t2r)),
            iqr_touch2robot=_iqr(t2r),
            statistic=statistic,
            p=p,
            p_holm=float(p_holm),
        )
        for (q, vf, t2r, n_zero, statistic, p), p_holm in zip(raw, adjusted, strict=True)
    )
    return UserStudyResult(tests=tests)
