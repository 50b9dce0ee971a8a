"""Contact-agreement and contact-onset metrics for evaluating replays against glove demonstrations.

Conventions shared by every function here:

* **Regions.** The last axis of a contact array is the region axis, ordered as
  ``schemas.tables.ROBOT_REGIONS`` (T1..T4, P1..P4) unless ``regions`` says otherwise.
  ``reference`` is the human glove (ground truth); ``evaluated`` is a sim/real/reconstructed
  sequence; "positive" means *contact*.
* **Scores.** TP/FP/FN/TN are counted over all time-region pairs, then
  precision = TP/(TP+FP), recall = TP/(TP+FN), F1 = 2TP/(2TP+FP+FN), FPR = FP/(FP+TN).
  An undefined ratio (0/0) is ``NaN`` -- never silently 0 or 1. In SQL it is ``NULL``
  (which pandas reads back as ``NaN``).
* **Alignment rule** (the same in Python and in ``sql/contact_metrics.sql``): an evaluated
  sample at reference time ``t_ref`` is compared with the reference sample of the same
  ``(reference_id, region)`` with the greatest ``t_ref <= `` the evaluated ``t_ref`` (a
  backward ASOF join, exact matches allowed); evaluated samples before the first reference
  sample, or whose ``reference_id`` has no reference rows, are dropped.
* **Onsets.** The onset of a region is the time of its first contact sample; contact already
  present at the first sample counts as an onset at that sample's time.

SQL twins live in ``touch2robot/sql/contact_metrics.sql`` (load with
:func:`register_contact_macros`): ``contact_pairs``/``contact_counts``/``contact_score_slices``
table macros and ``contact_precision``/``contact_recall``/``contact_f1``/``contact_fpr`` scalar
macros; tests assert they return exactly what :func:`contact_counts_long` and
:func:`contact_scores_table` return.

No orchestration (Prefect) imports: this module is a pure library.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from typing import TYPE_CHECKING, Literal, overload

import numpy as np
import pandas as pd

from schemas.tables import ROBOT_REGIONS
from schemas.vocabulary import Source

if TYPE_CHECKING:
    import duckdb

__all__ = [
    "ALL",
    "ContactScores",
    "ContactScoresByRegion",
    "OnsetErrors",
    "OnsetTrajectory",
    "align_to_reference",
    "contact_counts_long",
    "contact_macros_sql",
    "contact_scores",
    "contact_scores_table",
    "map_to_reference_time",
    "onset_error_ms",
    "onset_error_ms_long",
    "register_contact_macros",
]

ALL = "*"
"""Label of a rolled-up dimension in the SQL ``contact_score_slices`` macro (e.g. task = '*')."""

COUNT_COLUMNS: tuple[str, ...] = ("tp", "fp", "fn", "tn")
SCORE_COLUMNS: tuple[str, ...] = ("precision", "recall", "f1", "fpr")
CONTACT_KEYS: tuple[str, ...] = ("method", "task", "subject", "region")

# Elements per chunk in the counting loops: large enough to amortise Python overhead, small
# enough that the `a & b` temporary stays in cache (1 MiB of bools).
_CHUNK = 1 << 20


def _ratio(num: int, den: int) -> float:
    return num / den if den else float("nan")


@dataclass(frozen=True, slots=True)
class ContactScores:
    """Confusion counts of contact (positive) vs no contact, and the scores derived from them.

    Scores are properties so they can never disagree with the counts; each is ``NaN`` when its
    denominator is zero.
    """

    tp: int
    fp: int
    fn: int
    tn: int

    @property
    def n(self) -> int:
        """Number of compared time-region pairs."""
        return self.tp + self.fp + self.fn + self.tn

    @property
    def precision(self) -> float:
        """TP / (TP + FP); NaN when the evaluated sequence never reports contact."""
        return _ratio(self.tp, self.tp + self.fp)

    @property
    def recall(self) -> float:
        """TP / (TP + FN); NaN when the reference never has contact."""
        return _ratio(self.tp, self.tp + self.fn)

    @property
    def f1(self) -> float:
        """2TP / (2TP + FP + FN); NaN when neither side ever has contact."""
        return _ratio(2 * self.tp, 2 * self.tp + self.fp + self.fn)

    @property
    def fpr(self) -> float:
        """FP / (FP + TN); NaN when the reference is in contact everywhere."""
        return _ratio(self.fp, self.fp + self.tn)

    def as_dict(self) -> dict[str, int | float]:
        """Counts and scores as a flat dict (keys tp, fp, fn, tn, precision, recall, f1, fpr)."""
        return {
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
            "tn": self.tn,
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
            "fpr": self.fpr,
        }


@dataclass(frozen=True, slots=True)
class ContactScoresByRegion:
    """Overall scores plus one :class:`ContactScores` per region (keyed by region name)."""

    overall: ContactScores
    regions: Mapping[str, ContactScores]

    def to_frame(self) -> pd.DataFrame:
        """One row per region (in region order) with counts and scores."""
        rows = [{"region": name, **s.as_dict()} for name, s in self.regions.items()]
        return pd.DataFrame(rows, columns=["region", *COUNT_COLUMNS, *SCORE_COLUMNS])


def _as_binary(name: str, x: object) -> np.ndarray:
    """Return ``x`` as a bool array (no copy for bool input); 0/1 integers or floats are accepted."""
    a = np.asarray(x)
    if a.dtype == np.bool_:
        return a
    if a.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a bool or 0/1 numeric array; got dtype {a.dtype}")
    if a.size and not np.all((a == 0) | (a == 1)):
        raise ValueError(f"{name} must be binary: it holds values other than 0 and 1")
    return a.astype(bool)


def _check_pair(reference: object, evaluated: object) -> tuple[np.ndarray, np.ndarray]:
    ref = _as_binary("reference", reference)
    ev = _as_binary("evaluated", evaluated)
    for name, a in (("reference", ref), ("evaluated", ev)):
        if a.ndim < 2:
            raise ValueError(
                f"{name} must have shape (time, region) or (..., region); got shape {a.shape} "
                "(use a[:, None] for a single region)"
            )
    if ref.shape != ev.shape:
        raise ValueError(f"reference shape {ref.shape} != evaluated shape {ev.shape}")
    return ref, ev


def _counts_flat(ref: np.ndarray, ev: np.ndarray) -> ContactScores:
    # Only three popcounts are needed: TP = |r & e|, |r|, |e|; the rest follows from the total.
    # Chunking keeps the `r & e` temporary small (no full-size temporaries at all).
    r = ref.reshape(-1)
    e = ev.reshape(-1)
    buf = np.empty(min(r.size, _CHUNK), dtype=bool)
    tp = n_ref = n_ev = 0
    for start in range(0, r.size, _CHUNK):
        rc = r[start : start + _CHUNK]
        ec = e[start : start + _CHUNK]
        both = np.bitwise_and(rc, ec, out=buf[: rc.size])
        tp += np.count_nonzero(both)
        n_ref += np.count_nonzero(rc)
        n_ev += np.count_nonzero(ec)
    return ContactScores(tp=tp, fp=n_ev - tp, fn=n_ref - tp, tn=r.size - n_ref - n_ev + tp)


def _counts_per_region(ref: np.ndarray, ev: np.ndarray) -> list[ContactScores]:
    n_regions = ref.shape[-1]
    n_rows = math.prod(ref.shape[:-1])
    r = ref.reshape(n_rows, n_regions)
    e = ev.reshape(n_rows, n_regions)
    tp = np.zeros(n_regions, dtype=np.int64)
    n_ref = np.zeros(n_regions, dtype=np.int64)
    n_ev = np.zeros(n_regions, dtype=np.int64)
    rows = max(1, _CHUNK // max(n_regions, 1))
    for start in range(0, r.shape[0], rows):
        # A region-major copy of the chunk makes each region a contiguous run, so the fast
        # contiguous count_nonzero applies (column-strided counting is several times slower).
        rc = np.ascontiguousarray(r[start : start + rows].T)
        ec = np.ascontiguousarray(e[start : start + rows].T)
        both = rc & ec
        for k in range(n_regions):
            tp[k] += np.count_nonzero(both[k])
            n_ref[k] += np.count_nonzero(rc[k])
            n_ev[k] += np.count_nonzero(ec[k])
    return [
        ContactScores(
            tp=int(tp[k]),
            fp=int(n_ev[k] - tp[k]),
            fn=int(n_ref[k] - tp[k]),
            tn=int(n_rows - n_ref[k] - n_ev[k] + tp[k]),
        )
        for k in range(n_regions)
    ]


@overload
def contact_scores(
    reference: object,
    evaluated: object,
    regions: Sequence[str] | None = ...,
    per_region: Literal[False] = ...,
) -> ContactScores: ...
@overload
def contact_scores(
    reference: object,
    evaluated: object,
    regions: Sequence[str] | None = ...,
    *,
    per_region: Literal[True],
) -> ContactScoresByRegion: ...
def contact_scores(
    reference: object,
    evaluated: object,
    regions: Sequence[str] | None = None,
    per_region: bool = False,
) -> ContactScores | ContactScoresByRegion:
    """Confusion counts and precision/recall/F1/FPR of evaluated vs reference contact.

    Args:
        reference: ground-truth contact, shape ``(time, region)`` or stacked ``(..., region)``;
            bool, or integers/floats holding only 0 and 1. Contiguous bool input is never
            copied; counting works in cache-sized chunks without full-size temporaries.
        evaluated: same shape as ``reference``, already aligned sample by sample
            (see :func:`align_to_reference`).
        regions: names of the last axis; defaults to ``ROBOT_REGIONS`` (needed only for the
            per-region breakdown, validated whenever given).
        per_region: also return one :class:`ContactScores` per region.

    Returns:
        :class:`ContactScores` counted over all time-region pairs, or with ``per_region=True``
        a :class:`ContactScoresByRegion` whose ``overall`` equals the per-region sum.
        Empty input gives all-zero counts and NaN scores.

    Raises:
        ValueError: non-binary values, fewer than 2 dimensions, mismatched shapes, or
            ``regions`` not matching the last axis.
    """
    ref, ev = _check_pair(reference, evaluated)
    n_regions = ref.shape[-1]
    if regions is not None or per_region:
        names = tuple(ROBOT_REGIONS if regions is None else regions)
        if len(names) != n_regions or len(set(names)) != len(names):
            raise ValueError(
                f"regions must name each of the {n_regions} entries of the last axis once; got {list(names)}"
            )
    if not per_region:
        return _counts_flat(ref, ev)
    by_region = _counts_per_region(ref, ev)
    overall = ContactScores(
        tp=sum(s.tp for s in by_region),
        fp=sum(s.fp for s in by_region),
        fn=sum(s.fn for s in by_region),
        tn=sum(s.tn for s in by_region),
    )
    return ContactScoresByRegion(overall=overall, regions=dict(zip(names, by_region, strict=True)))


def _check_times(name: str, t: object) -> np.ndarray:
    a = np.asarray(t, dtype=np.float64)
    if a.ndim != 1:
        raise ValueError(f"{name} must be 1-D; got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (no NaN/inf)")
    return a


def align_to_reference(ref_t: object, ref_contacts: object, eval_t_ref: object) -> tuple[np.ndarray, np.ndarray]:
    """Pick, for every evaluated sample, the reference sample it is compared with.

    Alignment rule (backward ASOF join, identical to the SQL macros): the evaluated sample at
    reference time ``eval_t_ref[i]`` is compared with the reference sample with the greatest
    ``ref_t <= eval_t_ref[i]``; evaluated samples before ``ref_t[0]`` are dropped.

    Args:
        ref_t: reference sample times, 1-D, finite, strictly increasing (one reference
            sequence and region set; duplicates would make the match ambiguous).
        ref_contacts: reference rows, shape ``(len(ref_t), ...)``.
        eval_t_ref: evaluated sample times on the reference clock, 1-D, finite, any order
            (non-uniform and non-monotonic t_ref are fine).

    Returns:
        ``(aligned, kept)``: ``kept`` is a bool mask over the evaluated samples, ``aligned``
        holds ``ref_contacts`` rows for the kept samples, in evaluated order.
    """
    rt = _check_times("ref_t", ref_t)
    et = _check_times("eval_t_ref", eval_t_ref)
    rc = np.asarray(ref_contacts)
    if rc.ndim < 1 or rc.shape[0] != rt.size:
        raise ValueError(f"ref_contacts must have len(ref_t)={rt.size} rows; got shape {rc.shape}")
    if rt.size > 1 and not np.all(np.diff(rt) > 0):
        raise ValueError("ref_t must be strictly increasing")
    # side="right" makes exact matches (ref_t == eval t_ref) count, like `>=` in ASOF JOIN.
    idx = np.searchsorted(rt, et, side="right") - 1
    kept = idx >= 0
    return rc[idx[kept]], kept


_LONG_COLUMNS = ("source", "sequence_id", "reference_id", "t", "t_ref", "region", "contact")


def _check_long(contacts: pd.DataFrame, needed: Iterable[str]) -> None:
    missing = [c for c in needed if c not in contacts.columns]
    if missing:
        raise ValueError(f"contacts is missing columns {missing}")


def _reference_rows(contacts: pd.DataFrame, ref_source: str) -> pd.DataFrame:
    ref = contacts[contacts["source"] == ref_source]
    per_ref = ref.groupby("reference_id", sort=False)["sequence_id"].nunique()
    ambiguous = per_ref[per_ref > 1]
    if len(ambiguous):
        raise ValueError(
            f"reference source {ref_source!r} has several sequences for reference_id "
            f"{ambiguous.index[0]!r}; the reference must be unique per reference_id "
            "(filter the rows to one method first)"
        )
    return ref


def contact_counts_long(
    contacts: pd.DataFrame, *, ref_source: str = Source.HUMAN, eval_source: str, keys: Sequence[str] = CONTACT_KEYS
) -> pd.DataFrame:
    """TP/FP/FN/TN per (method, task, subject, region) straight from the long ``contacts`` table.

    Python twin of the SQL table macro ``contact_counts(ref_source, eval_source)``; both return
    the same rows. Each ``eval_source`` row is aligned to the ``ref_source`` rows of the same
    ``(reference_id, region)`` with :func:`align_to_reference` (backward ASOF on ``t_ref``;
    samples before the first reference sample are dropped). method/task/subject are those of
    the evaluated rows. The reference source must hold one sequence per reference_id (true for
    ``"human"``, where ``reference_id == sequence_id``).

    ``keys`` (columns of the evaluated rows) are what the counts are summed by; e.g. ``("method",
    "task", "reference_id")`` gives one row per demonstration scored.

    Returns:
        DataFrame with the ``keys`` columns (default method, task, subject, region) and tp, fp, fn,
        tn (int64), sorted by the keys; groups with no aligned sample are absent.
    """
    _check_long(contacts, (*_LONG_COLUMNS, *keys))
    ref = _reference_rows(contacts, ref_source)
    ev = contacts[contacts["source"] == eval_source]
    ref_groups = {k: g for k, g in ref.groupby(["reference_id", "region"], sort=False)}
    parts = []
    for key, eg in ev.groupby(["reference_id", "region"], sort=False):
        rg = ref_groups.get(key)
        if rg is None:
            continue
        order = np.argsort(rg["t_ref"].to_numpy(), kind="stable")
        ref_t = rg["t_ref"].to_numpy()[order]
        if ref_t.size > 1 and not np.all(np.diff(ref_t) > 0):
            raise ValueError(f"reference {key[0]!r} region {key[1]!r} has duplicate t_ref values")
        aligned, kept = align_to_reference(ref_t, rg["contact"].to_numpy(dtype=bool)[order], eg["t_ref"].to_numpy())
        part = eg.loc[kept, list(keys)]
        e = eg["contact"].to_numpy(dtype=bool)[kept]
        parts.append(part.assign(tp=aligned & e, fp=~aligned & e, fn=aligned & ~e, tn=~aligned & ~e))
    if not parts:
        out = pd.DataFrame({k: pd.Series(dtype=object) for k in keys})
        return out.assign(**{c: pd.Series(dtype=np.int64) for c in COUNT_COLUMNS})
    flags = pd.concat(parts, ignore_index=True)
    counts = flags.groupby(list(keys), sort=True)[list(COUNT_COLUMNS)].sum()
    return counts.astype(np.int64).reset_index()


def contact_scores_table(counts: pd.DataFrame, by: Sequence[str] = ("method", "task")) -> pd.DataFrame:
    """Sum ``counts`` (from :func:`contact_counts_long`) over everything not in ``by`` and score it.

    Returns the ``by`` columns, tp/fp/fn/tn and precision/recall/f1/fpr (float64, NaN for 0/0),
    sorted by ``by``; matches the SQL ``contact_score_slices`` rows whose other dimensions are
    ``'*'``.
    """
    summed = counts.groupby(list(by), sort=True)[list(COUNT_COLUMNS)].sum().reset_index()
    tp, fp, fn, tn = (summed[c].to_numpy(dtype=np.int64) for c in COUNT_COLUMNS)
    scores = {
        "precision": (tp, tp + fp),
        "recall": (tp, tp + fn),
        "f1": (2 * tp, 2 * tp + fp + fn),
        "fpr": (fp, fp + tn),
    }
    for name, (num, den) in scores.items():
        out = np.full(num.shape, np.nan)
        np.divide(num, den, out=out, where=den != 0)
        summed[name] = out
    return summed


def register_contact_macros(con: duckdb.DuckDBPyConnection) -> None:
    """Create the DuckDB macros of ``touch2robot/sql/contact_metrics.sql`` on ``con``.

    DuckDB binds table macros when they are created, so a table or view named ``contacts``
    (columns as ``schemas.tables.contacts``) must exist first; the macros then follow any later
    redefinition of that view. See the SQL file for the macro names and how to call them.
    """
    con.execute(contact_macros_sql())


def contact_macros_sql() -> str:
    """The statements of ``touch2robot/sql/contact_metrics.sql`` (see :func:`register_contact_macros`)."""
    return resources.files("touch2robot.sql").joinpath("contact_metrics.sql").read_text()


# --------------------------------------------------------------------------- onsets


@dataclass(frozen=True, slots=True, eq=False)
class OnsetTrajectory:
    """One evaluated trajectory and the reference it replays, in array form.

    Attributes:
        trajectory: name used in the per-pair table (e.g. the evaluated sequence_id).
        ref_t: reference sample times (reference clock), shape ``(n_ref,)``.
        ref_contacts: reference contact, shape ``(n_ref, n_regions)``.
        eval_t: evaluated sample times on the evaluated (replay) clock, shape ``(n_eval,)``.
        eval_contacts: evaluated contact, shape ``(n_eval, n_regions)``.
        time_map_t, time_map_t_ref: the recorded time map as (replay time, reference time)
            pairs; ``None`` for both means ``eval_t`` is already on the reference clock.
    """

    trajectory: str
    ref_t: np.ndarray
    ref_contacts: np.ndarray
    eval_t: np.ndarray
    eval_contacts: np.ndarray
    time_map_t: np.ndarray | None = None
    time_map_t_ref: np.ndarray | None = None


@dataclass(frozen=True, slots=True, eq=False)
class OnsetErrors:
    """Contact-onset timing error.

    Attributes:
        e_ms: E = 1000/N * sum |t_eval_onset - t_ref_onset| over valid pairs, in ms; NaN if N = 0.
        n: N, the number of valid trajectory-region pairs (an onset on both sides).
        n_missing_reference: pairs whose reference has no onset (including n_missing_both).
        n_missing_evaluated: pairs whose evaluated sequence has no onset (including
            n_missing_both).
        n_missing_both: pairs with no onset on either side.
        pairs: one row per trajectory-region pair: trajectory, region, t_ref_onset,
            t_eval_onset (reference clock), error_ms, valid (onsets are NaN when missing,
            error_ms NaN when invalid). The long-form entry point adds method, task,
            subject and reference_id columns.
    """

    e_ms: float
    n: int
    n_missing_reference: int
    n_missing_evaluated: int
    n_missing_both: int
    pairs: pd.DataFrame = field(repr=False)

    @property
    def n_invalid(self) -> int:
        """Pairs lacking an onset on at least one side."""
        return self.n_missing_reference + self.n_missing_evaluated - self.n_missing_both


def map_to_reference_time(t: object, map_t: object, map_t_ref: object) -> np.ndarray:
    """Map evaluated (replay) times onto the reference clock with the recorded time map.

    Linear interpolation (``np.interp``) between the ``(map_t, map_t_ref)`` pairs. Times outside
    ``[map_t[0], map_t[-1]]`` have no reference time and map to ``NaN`` (``np.interp`` would
    silently clamp them to the ends); such samples take no part in onset detection.

    Raises:
        ValueError: ``map_t`` not strictly increasing, ``map_t_ref`` decreasing, lengths
            differing, an empty map, or non-finite values.
    """
    tt = np.asarray(t, dtype=np.float64)
    mt = _check_times("time map t", map_t)
    mr = _check_times("time map t_ref", map_t_ref)
    if mt.size != mr.size or mt.size == 0:
        raise ValueError(f"time map needs equally long, non-empty t and t_ref; got {mt.size} and {mr.size}")
    if not np.all(np.diff(mt) > 0):
        raise ValueError("time map t (replay time) must be strictly increasing")
    if not np.all(np.diff(mr) >= 0):
        raise ValueError("time map t_ref must be non-decreasing")
    out = np.interp(tt, mt, mr)
    out[(tt < mt[0]) | (tt > mt[-1])] = np.nan
    return out


def _first_onsets(t: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """Per region, the time of the first contact sample (NaN if none); samples need not be sorted.

    The first contact sample is always an onset: either it is the first sample (contact from
    the start counts as an onset at that time) or it follows a no-contact sample.
    """
    times = np.where(contacts, t[:, None], np.inf)
    first = times.min(axis=0, initial=np.inf)
    return np.where(np.isfinite(first), first, np.nan)


def _summarise(pairs: pd.DataFrame) -> OnsetErrors:
    ref_on = pairs["t_ref_onset"].to_numpy(dtype=np.float64)
    ev_on = pairs["t_eval_onset"].to_numpy(dtype=np.float64)
    miss_ref = np.isnan(ref_on)
    miss_ev = np.isnan(ev_on)
    valid = ~(miss_ref | miss_ev)
    abs_diff = np.abs(ev_on - ref_on)
    extra = [c for c in pairs.columns if c not in ("trajectory", "region", "t_ref_onset", "t_eval_onset")]
    pairs = pairs.assign(error_ms=np.where(valid, 1000.0 * abs_diff, np.nan), valid=valid)
    pairs = pairs[["trajectory", "region", "t_ref_onset", "t_eval_onset", "error_ms", "valid", *extra]]
    n = int(valid.sum())
    return OnsetErrors(
        e_ms=1000.0 / n * float(abs_diff[valid].sum()) if n else float("nan"),
        n=n,
        n_missing_reference=int(miss_ref.sum()),
        n_missing_evaluated=int(miss_ev.sum()),
        n_missing_both=int((miss_ref & miss_ev).sum()),
        pairs=pairs.reset_index(drop=True),
    )


def onset_error_ms(trajectories: Iterable[OnsetTrajectory], regions: Sequence[str] = ROBOT_REGIONS) -> OnsetErrors:
    """Contact-onset timing error E (ms) over trajectory-region pairs.

    For each trajectory and region: the reference onset is the first reference contact sample;
    the evaluated onset is the first evaluated contact sample *inside the time map's range*
    (samples outside it have no reference time, see :func:`map_to_reference_time`), mapped to
    the reference clock. Contact at the first sample counts as an onset at that sample's time.
    A pair is valid only when both sides have an onset; E = 1000/N * sum |t_eval - t_ref|.

    Args:
        trajectories: one :class:`OnsetTrajectory` per evaluated trajectory.
        regions: names of the contact arrays' last axis.
    """
    rows = []
    for tr in trajectories:
        ref_t = _check_times(f"{tr.trajectory}: ref_t", tr.ref_t)
        ev_t = _check_times(f"{tr.trajectory}: eval_t", tr.eval_t)
        ref_c = _as_binary(f"{tr.trajectory}: ref_contacts", tr.ref_contacts)
        ev_c = _as_binary(f"{tr.trajectory}: eval_contacts", tr.eval_contacts)
        for name, c, t in (("ref_contacts", ref_c, ref_t), ("eval_contacts", ev_c, ev_t)):
            if c.shape != (t.size, len(regions)):
                raise ValueError(f"{tr.trajectory}: {name} must have shape ({t.size}, {len(regions)}); got {c.shape}")
        if (tr.time_map_t is None) != (tr.time_map_t_ref is None):
            raise ValueError(f"{tr.trajectory}: give both time_map_t and time_map_t_ref or neither")
        ev_ref_t = ev_t if tr.time_map_t is None else map_to_reference_time(ev_t, tr.time_map_t, tr.time_map_t_ref)
        in_map = ~np.isnan(ev_ref_t)
        ref_on = _first_onsets(ref_t, ref_c)
        # The onset is found on the replay clock and then mapped: the map is monotone, so this
        # equals the earliest mapped contact time, and it keeps replay-clock order authoritative.
        ev_on_replay = _first_onsets(ev_t[in_map], ev_c[in_map])
        ev_on = np.full(len(regions), np.nan)
        has = ~np.isnan(ev_on_replay)
        if tr.time_map_t is None:
            ev_on[has] = ev_on_replay[has]
        else:
            ev_on[has] = map_to_reference_time(ev_on_replay[has], tr.time_map_t, tr.time_map_t_ref)
        rows.extend((tr.trajectory, region, ref_on[k], ev_on[k]) for k, region in enumerate(regions))
    pairs = pd.DataFrame(rows, columns=["trajectory", "region", "t_ref_onset", "t_eval_onset"])
    return _summarise(pairs.astype({"t_ref_onset": np.float64, "t_eval_onset": np.float64}))


def onset_error_ms_long(
    contacts: pd.DataFrame,
    time_map: pd.DataFrame,
    *,
    eval_source: str,
    ref_source: str = Source.HUMAN,
    on_missing_time_map: Literal["raise", "use_t_ref"] = "raise",
) -> OnsetErrors:
    """:func:`onset_error_ms` straight from the long ``contacts`` and ``time_map`` tables.

    Each ``eval_source`` sequence (``sequence_id``) is one trajectory, compared with the
    ``ref_source`` rows of its ``reference_id`` (reference onsets use ``t_ref``, which equals
    ``t`` for the glove). Evaluated onsets use the sequence's own clock ``t`` mapped through the
    ``time_map`` rows whose ``recording_id`` is the sequence_id. A sequence without time-map
    rows raises, or with ``on_missing_time_map="use_t_ref"`` uses the ``t_ref`` column already
    stored in the contacts rows (e.g. simulated rollouts that run on the reference clock).
    The regions of a trajectory are those present on either side; a region without rows on one
    side counts as having no onset there.

    Returns:
        :class:`OnsetErrors` whose pairs table also carries method, task, subject and
        reference_id (of the evaluated sequence); ``trajectory`` is the evaluated sequence_id.
    """
    _check_long(contacts, (*_LONG_COLUMNS, "method", "task", "subject"))
    missing = [c for c in ("recording_id", "t", "t_ref") if c not in time_map.columns]
    if missing:
        raise ValueError(f"time_map is missing columns {missing}")
    if on_missing_time_map not in ("raise", "use_t_ref"):
        raise ValueError(f"on_missing_time_map must be 'raise' or 'use_t_ref'; got {on_missing_time_map!r}")
    ref = _reference_rows(contacts, ref_source)
    ref_onsets = ref[ref["contact"].to_numpy(dtype=bool)].groupby(["reference_id", "region"])["t_ref"].min()
    ref_regions = ref.groupby("reference_id")["region"].unique()
    maps = {k: g.sort_values("t") for k, g in time_map.groupby("recording_id", sort=False)}
    rows = []
    for seq, eg in contacts[contacts["source"] == eval_source].groupby("sequence_id", sort=True):
        for col in ("reference_id", "method", "task", "subject"):
            if eg[col].nunique() != 1:
                raise ValueError(f"evaluated sequence {seq!r} has several {col} values")
        first = eg.iloc[0]
        ref_id = first["reference_id"]
        tm = maps.get(seq)
        if tm is not None:
            ev_ref_t = map_to_reference_time(eg["t"], tm["t"], tm["t_ref"])
        elif on_missing_time_map == "use_t_ref":
            ev_ref_t = _check_times(f"{seq}: t_ref", eg["t_ref"])
        else:
            raise ValueError(
                f"evaluated sequence {seq!r} has no time_map rows "
                "(pass on_missing_time_map='use_t_ref' to use its stored t_ref)"
            )
        # Monotone map: the earliest mapped contact time is the mapped first contact on the
        # replay clock; NaN (outside the map) samples are ignored by min().
        hits = eg.assign(_t=ev_ref_t)[eg["contact"].to_numpy(dtype=bool)]
        ev_onsets = hits.groupby("region")["_t"].min()
        regions = sorted(
            set(eg["region"]) | set(ref_regions.get(ref_id, ())),
            key=lambda r: (ROBOT_REGIONS.index(r) if r in ROBOT_REGIONS else len(ROBOT_REGIONS), r),
        )
        for region in regions:
            rows.append(
                (
                    seq,
                    region,
                    ref_onsets.get((ref_id, region), np.nan),
                    ev_onsets.get(region, np.nan),
                    first["method"],
                    first["task"],
                    first["subject"],
                    ref_id,
                )
            )
    pairs = pd.DataFrame(
        rows,
        columns=[
            "trajectory",
            "region",
            "t_ref_onset",
            "t_eval_onset",
            "method",
            "task",
            "subject",
            "reference_id",
        ],
    )
    return _summarise(pairs.astype({"t_ref_onset": np.float64, "t_eval_onset": np.float64}))
