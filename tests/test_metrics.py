"""touch2robot.metrics: contact scores vs scikit-learn, alignment, onset error."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from sklearn.metrics import confusion_matrix, f1_score, precision_score, recall_score

from schemas.tables import ROBOT_REGIONS
from touch2robot import metrics
from touch2robot.metrics import (
    ContactScores,
    OnsetTrajectory,
    align_to_reference,
    contact_counts_long,
    contact_scores,
    contact_scores_table,
    map_to_reference_time,
    onset_error_ms,
    onset_error_ms_long,
)


def _sklearn_counts(ref: np.ndarray, ev: np.ndarray) -> tuple[int, int, int, int]:
    if ref.size == 0:  # scikit-learn rejects empty input; there is nothing to count
        return 0, 0, 0, 0
    tn, fp, fn, tp = confusion_matrix(ref.ravel(), ev.ravel(), labels=[False, True]).ravel()
    return int(tp), int(fp), int(fn), int(tn)


def _assert_scores_match_sklearn(s: ContactScores, ref: np.ndarray, ev: np.ndarray) -> None:
    assert (s.tp, s.fp, s.fn, s.tn) == _sklearn_counts(ref, ev)
    r, e = ref.ravel(), ev.ravel()
    expected_defined = {
        "precision": s.tp + s.fp > 0,
        "recall": s.tp + s.fn > 0,
        "f1": s.tp + s.fp + s.fn > 0,
        "fpr": s.fp + s.tn > 0,
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sk = {
            "precision": precision_score(r, e, zero_division=np.nan) if r.size else math.nan,  # pyright: ignore[reportArgumentType]
            "recall": recall_score(r, e, zero_division=np.nan) if r.size else math.nan,  # pyright: ignore[reportArgumentType]
            "f1": f1_score(r, e, zero_division=np.nan) if r.size else math.nan,  # pyright: ignore[reportArgumentType]
        }
    fpr = s.fp / (s.fp + s.tn) if s.fp + s.tn else math.nan
    for name, defined in expected_defined.items():
        ours = getattr(s, name)
        if not defined:
            assert math.isnan(ours), name
            continue
        expected = fpr if name == "fpr" else sk[name]
        assert ours == pytest.approx(expected, rel=1e-12, abs=0), name


binary = st.integers(0, 40).flatmap(
    lambda t: st.integers(1, 8).flatmap(
        lambda r: st.tuples(
            arrays(np.bool_, (t, r)),
            arrays(np.bool_, (t, r)),
        )
    )
)


@settings(max_examples=200, deadline=None)
@given(binary)
def test_contact_scores_match_sklearn(pair: tuple[np.ndarray, np.ndarray]) -> None:
    ref, ev = pair
    _assert_scores_match_sklearn(contact_scores(ref, ev), ref, ev)


@settings(max_examples=100, deadline=None)
@given(binary)
def test_per_region_matches_sklearn_per_column(pair: tuple[np.ndarray, np.ndarray]) -> None:
    ref, ev = pair
    names = [f"R{k}" for k in range(ref.shape[1])]
    res = contact_scores(ref, ev, regions=names, per_region=True)
    assert list(res.regions) == names
    for k, name in enumerate(names):
        _assert_scores_match_sklearn(res.regions[name], ref[:, k], ev[:, k])
    assert res.overall == contact_scores(ref, ev)
    frame = res.to_frame()
    assert list(frame["region"]) == names
    assert frame["tp"].sum() == res.overall.tp


@pytest.mark.parametrize("shape", [(0, 8), (5, 0), (0, 0), (3, 0, 8)])
def test_empty_arrays_give_zero_counts_and_nan_scores(shape: tuple[int, ...]) -> None:
    z = np.zeros(shape, dtype=bool)
    s = contact_scores(z, z)
    assert (s.tp, s.fp, s.fn, s.tn) == (0, 0, 0, 0)
    assert all(math.isnan(getattr(s, k)) for k in ("precision", "recall", "f1", "fpr"))


def test_all_zero_and_all_one_cases() -> None:
    zeros = np.zeros((10, 8), dtype=bool)
    ones = np.ones((10, 8), dtype=bool)
    s = contact_scores(zeros, zeros)
    assert (s.tp, s.fp, s.fn, s.tn) == (0, 0, 0, 80)
    assert math.isnan(s.precision) and math.isnan(s.recall) and math.isnan(s.f1)
    assert s.fpr == 0.0
    s = contact_scores(ones, ones)
    assert (s.tp, s.fp, s.fn, s.tn) == (80, 0, 0, 0)
    assert (s.precision, s.recall, s.f1) == (1.0, 1.0, 1.0)
    assert math.isnan(s.fpr)
    s = contact_scores(ones, zeros)
    assert math.isnan(s.precision) and s.recall == 0.0 and s.f1 == 0.0 and math.isnan(s.fpr)


def test_as_dict_has_counts_and_scores() -> None:
    s = contact_scores(np.array([[1, 0], [1, 1]]), np.array([[1, 1], [0, 1]]))
    assert s.as_dict() == {
        "tp": 2,
        "fp": 1,
        "fn": 1,
        "tn": 0,
        "precision": 2 / 3,
        "recall": 2 / 3,
        "f1": 4 / 6,
        "fpr": 1.0,
    }


def test_stacked_non_contiguous_and_chunked(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(3)
    ref = rng.random((4, 37, 8)) < 0.4
    ev = ref ^ (rng.random((4, 37, 8)) < 0.2)
    expected = _sklearn_counts(ref, ev)
    # Small chunks exercise the chunk loops and a ragged last chunk.
    monkeypatch.setattr(metrics, "_CHUNK", 13)
    s = contact_scores(ref, ev)
    assert (s.tp, s.fp, s.fn, s.tn) == expected
    by = contact_scores(ref, ev, per_region=True)
    assert by.overall == s
    assert list(by.regions) == list(ROBOT_REGIONS)
    for k, name in enumerate(ROBOT_REGIONS):
        c = by.regions[name]
        assert (c.tp, c.fp, c.fn, c.tn) == _sklearn_counts(ref[..., k], ev[..., k])
    # Transposed / strided views are handled without the caller copying.
    rt = np.swapaxes(ref, 0, 1)
    et = np.swapaxes(ev, 0, 1)
    assert contact_scores(rt, et) == s
    assert contact_scores(ref[:, ::2], ev[:, ::2]) == ContactScores(*_sklearn_counts(ref[:, ::2], ev[:, ::2]))


def test_numeric_binary_inputs_are_accepted() -> None:
    ref = np.array([[1, 0], [0, 1]], dtype=np.int8)
    ev = np.array([[1.0, 1.0], [0.0, 0.0]])
    assert contact_scores(ref, ev) == ContactScores(tp=1, fp=1, fn=1, tn=1)


@pytest.mark.parametrize(
    ("ref", "ev", "kwargs", "match"),
    [
        (np.array([[0, 2]]), np.array([[0, 1]]), {}, "reference must be binary"),
        (np.array([[0, 1]]), np.array([[0.5, 1]]), {}, "evaluated must be binary"),
        (np.array([[0, 1]]), np.array([[np.nan, 1]]), {}, "evaluated must be binary"),
        (np.array([["a", "b"]]), np.array([[0, 1]]), {}, "reference must be a bool"),
        (np.zeros(4, bool), np.zeros(4, bool), {}, r"reference must have shape \(time, region\)"),
        (np.zeros((4, 8), bool), np.zeros((4, 7), bool), {}, "reference shape"),
        (np.zeros((4, 3), bool), np.zeros((4, 3), bool), {"per_region": True}, "regions must name"),
        (np.zeros((4, 2), bool), np.zeros((4, 2), bool), {"regions": ["a", "a"]}, "regions must name"),
    ],
)
def test_contact_scores_validation(ref, ev, kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        contact_scores(ref, ev, **kwargs)


# --------------------------------------------------------------------------- alignment


def test_align_to_reference_backward_asof() -> None:
    ref_t = np.array([0.0, 0.1, 0.25, 0.4])
    ref_c = np.array([[1, 0], [0, 0], [1, 1], [0, 1]], dtype=bool)
    eval_t = np.array([-0.05, 0.0, 0.05, 0.25, 0.3999, 7.0, 0.1])
    aligned, kept = align_to_reference(ref_t, ref_c, eval_t)
    assert kept.tolist() == [False, True, True, True, True, True, True]
    np.testing.assert_array_equal(aligned, ref_c[[0, 0, 2, 2, 3, 1]])


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.floats(-10, 10, allow_nan=False), min_size=1, max_size=30, unique=True),
    st.lists(st.floats(-12, 12, allow_nan=False), max_size=30),
)
def test_align_to_reference_matches_brute_force(ref: list[float], ev: list[float]) -> None:
    ref_t = np.sort(np.array(ref))
    rows = np.arange(ref_t.size)
    aligned, kept = align_to_reference(ref_t, rows, np.array(ev))
    expected = [max((i for i, r in enumerate(ref_t) if r <= e), default=None) for e in ev]
    assert kept.tolist() == [x is not None for x in expected]
    assert aligned.tolist() == [x for x in expected if x is not None]


@pytest.mark.parametrize(
    ("ref_t", "ref_c", "eval_t", "match"),
    [
        ([0.0, 0.0], [1, 0], [0.5], "strictly increasing"),
        ([0.0, 1.0], [1, 0, 1], [0.5], "ref_contacts must have"),
        ([0.0, np.nan], [1, 0], [0.5], "ref_t must be finite"),
        ([0.0, 1.0], [1, 0], [np.nan], "eval_t_ref must be finite"),
        ([[0.0, 1.0]], [1, 0], [0.5], "ref_t must be 1-D"),
    ],
)
def test_align_validation(ref_t, ref_c, eval_t, match) -> None:
    with pytest.raises(ValueError, match=match):
        align_to_reference(ref_t, np.array(ref_c), eval_t)


def _long(rows: list[tuple]) -> pd.DataFrame:
    cols = ["source", "method", "task", "subject", "sequence_id", "reference_id", "t", "t_ref", "region", "contact"]
    return pd.DataFrame(rows, columns=cols).assign(value=np.float32(np.nan))


def test_contact_counts_long_hand_example() -> None:
    h = [
        ("human", "human", "pick", "s1", "h1", "h1", t, t, "T1", c) for t, c in [(0.0, True), (1.0, False), (2.0, True)]
    ]
    e = [
        ("sim", "m", "pick", "s1", "x1", "h1", t, tr, "T1", c)
        for t, tr, c in [(0.0, -0.5, True), (0.1, 0.0, True), (0.2, 1.5, False), (0.3, 2.0, True)]
    ]
    orphan = [("sim", "m", "pick", "s1", "x2", "missing", 0.0, 1.0, "T1", True)]
    counts = contact_counts_long(_long(h + e + orphan), eval_source="sim")
    assert counts.to_dict("records") == [
        {"method": "m", "task": "pick", "subject": "s1", "region": "T1", "tp": 2, "fp": 0, "fn": 0, "tn": 1}
    ]
    scored = contact_scores_table(counts, by=["method"])
    assert scored[["precision", "recall", "f1", "fpr"]].iloc[0].tolist() == [1.0, 1.0, 1.0, 0.0]
    empty = contact_counts_long(_long(h), eval_source="real")
    assert list(empty.columns) == ["method", "task", "subject", "region", "tp", "fp", "fn", "tn"]
    assert empty.empty


def test_contact_counts_long_rejects_ambiguous_reference() -> None:
    rows = [("sim", m, "pick", "s1", f"x{m}", "h1", 0.0, 0.0, "T1", True) for m in ("a", "b")]
    with pytest.raises(ValueError, match="several sequences for reference_id 'h1'"):
        contact_counts_long(_long(rows), ref_source="sim", eval_source="sim")


# --------------------------------------------------------------------------- onsets

REGIONS2 = ("T1", "P1")


def _traj_a() -> OnsetTrajectory:
    # Replay runs at half speed: reference time = replay time / 2.
    ref_t = np.round(np.arange(11) * 0.1, 10)
    ref_c = np.zeros((11, 2), dtype=bool)
    ref_c[3:7, 0] = True  # T1 onset at 0.3
    ref_c[:4, 1] = True  # P1 in contact from the first sample: onset at 0.0
    ev_t = np.round(np.arange(21) * 0.1, 10)
    ev_c = np.zeros((21, 2), dtype=bool)
    ev_c[8:12, 0] = True  # T1 onset at replay 0.8 -> ref 0.4 (100 ms late)
    ev_c[:3, 1] = True  # P1 from the first sample -> ref 0.0 (0 ms)
    ev_c[15:, 1] = True  # a later second onset must be ignored
    return OnsetTrajectory("A", ref_t, ref_c, ev_t, ev_c, np.array([0.0, 2.0]), np.array([0.0, 1.0]))


def _traj_b() -> OnsetTrajectory:
    # T1: reference never in contact; P1: evaluated never in contact. Identity clock.
    t = np.linspace(0.0, 1.0, 6)
    ref_c = np.column_stack([np.zeros(6, bool), t >= 0.4])
    ev_c = np.column_stack([t >= 0.2, np.zeros(6, bool)])
    return OnsetTrajectory("B", t, ref_c, t, ev_c)


def _traj_c() -> OnsetTrajectory:
    # Offset map: reference = replay - 0.25, defined on replay [0.25, 2.0]. T1: no onset on
    # either side. P1: contact at replay 0.1 lies outside the map and is ignored; the onset
    # is at replay 0.6 -> ref 0.35 vs reference onset 0.3 (50 ms).
    ref_t = np.round(np.arange(11) * 0.1, 10)
    ref_c = np.zeros((11, 2), dtype=bool)
    ref_c[3:, 1] = True
    ev_t = np.round(np.arange(21) * 0.1, 10)
    ev_c = np.zeros((21, 2), dtype=bool)
    ev_c[1, 1] = True
    ev_c[6:, 1] = True
    return OnsetTrajectory("C", ref_t, ref_c, ev_t, ev_c, np.array([0.25, 1.0, 2.0]), np.array([0.0, 0.75, 1.75]))


def test_onset_error_known_answers() -> None:
    res = onset_error_ms([_traj_a(), _traj_b(), _traj_c()], regions=REGIONS2)
    p = res.pairs
    assert list(p.columns) == ["trajectory", "region", "t_ref_onset", "t_eval_onset", "error_ms", "valid"]
    assert list(zip(p["trajectory"], p["region"], strict=True)) == [
        ("A", "T1"),
        ("A", "P1"),
        ("B", "T1"),
        ("B", "P1"),
        ("C", "T1"),
        ("C", "P1"),
    ]
    assert p["valid"].tolist() == [True, True, False, False, False, True]
    np.testing.assert_allclose(p["t_ref_onset"], [0.3, 0.0, np.nan, 0.4, np.nan, 0.3])
    np.testing.assert_allclose(p["t_eval_onset"], [0.4, 0.0, 0.2, np.nan, np.nan, 0.35])
    np.testing.assert_allclose(p["error_ms"], [100.0, 0.0, np.nan, np.nan, np.nan, 50.0])
    assert res.n == 3
    assert res.e_ms == pytest.approx(1000 / 3 * (0.1 + 0.0 + 0.05))
    assert (res.n_missing_reference, res.n_missing_evaluated, res.n_missing_both) == (2, 2, 1)
    assert res.n_invalid == 3


def test_onset_error_no_valid_pairs_is_nan() -> None:
    res = onset_error_ms([_traj_b()], regions=REGIONS2)
    assert res.n == 0 and math.isnan(res.e_ms)
    empty = onset_error_ms([], regions=REGIONS2)
    assert empty.n == 0 and math.isnan(empty.e_ms) and empty.pairs.empty


def test_map_to_reference_time_outside_range_is_nan() -> None:
    out = map_to_reference_time([-0.1, 0.0, 1.0, 2.0, 2.5], [0.0, 2.0], [1.0, 2.0])
    np.testing.assert_allclose(out, [np.nan, 1.0, 1.5, 2.0, np.nan])


@pytest.mark.parametrize(
    ("map_t", "map_t_ref", "match"),
    [
        ([0.0, 0.0], [0.0, 1.0], "strictly increasing"),
        ([0.0, 1.0], [1.0, 0.0], "non-decreasing"),
        ([0.0, 1.0], [0.0], "equally long"),
        ([], [], "non-empty"),
    ],
)
def test_time_map_validation(map_t, map_t_ref, match) -> None:
    with pytest.raises(ValueError, match=match):
        map_to_reference_time([0.5], map_t, map_t_ref)


def test_onset_validation() -> None:
    tr = _traj_a()
    bad = OnsetTrajectory("X", tr.ref_t, tr.ref_contacts[:, :1], tr.eval_t, tr.eval_contacts)
    with pytest.raises(ValueError, match="X: ref_contacts must have shape"):
        onset_error_ms([bad], regions=REGIONS2)
    half = OnsetTrajectory("Y", tr.ref_t, tr.ref_contacts, tr.eval_t, tr.eval_contacts, tr.time_map_t)
    with pytest.raises(ValueError, match="Y: give both"):
        onset_error_ms([half], regions=REGIONS2)


def _to_long(tr: OnsetTrajectory, source: str, reference_id: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    rows = []
    for k, region in enumerate(REGIONS2):
        for t, c in zip(tr.ref_t, tr.ref_contacts[:, k], strict=True):
            rows.append(("human", "human", "pick", "s1", reference_id, reference_id, t, t, region, c))
        for t, c in zip(tr.eval_t, tr.eval_contacts[:, k], strict=True):
            # Stored t_ref deliberately differs from the time map (replay clock) to show which
            # one is used.
            rows.append((source, "m", "pick", "s1", tr.trajectory, reference_id, t, t, region, c))
    tm = pd.DataFrame(columns=["recording_id", "t", "t_ref"])
    if tr.time_map_t is not None:
        tm = pd.DataFrame({"recording_id": tr.trajectory, "t": tr.time_map_t, "t_ref": tr.time_map_t_ref})
    return _long(rows), tm


def test_onset_error_long_matches_record_form() -> None:
    parts = [_to_long(tr, "real", f"h{tr.trajectory}") for tr in (_traj_a(), _traj_c())]
    contacts = pd.concat([p[0] for p in parts], ignore_index=True)
    time_map = pd.concat([p[1] for p in parts], ignore_index=True)
    res = onset_error_ms_long(contacts, time_map, eval_source="real")
    rec = onset_error_ms([_traj_a(), _traj_c()], regions=REGIONS2)
    assert res.e_ms == pytest.approx(rec.e_ms)
    assert (res.n, res.n_missing_reference, res.n_missing_evaluated, res.n_missing_both) == (
        rec.n,
        rec.n_missing_reference,
        rec.n_missing_evaluated,
        rec.n_missing_both,
    )
    base = ["trajectory", "region", "t_ref_onset", "t_eval_onset", "error_ms", "valid"]
    pd.testing.assert_frame_equal(res.pairs[base], rec.pairs[base], check_exact=False)
    assert res.pairs[["method", "task", "subject"]].drop_duplicates().values.tolist() == [["m", "pick", "s1"]]
    assert set(res.pairs["reference_id"]) == {"hA", "hC"}


def test_onset_error_long_missing_time_map() -> None:
    contacts, _ = _to_long(_traj_b(), "sim", "hB")
    empty_map = pd.DataFrame(columns=["recording_id", "t", "t_ref"])
    with pytest.raises(ValueError, match="'B' has no time_map rows"):
        onset_error_ms_long(contacts, empty_map, eval_source="sim")
    res = onset_error_ms_long(contacts, empty_map, eval_source="sim", on_missing_time_map="use_t_ref")
    rec = onset_error_ms([_traj_b()], regions=REGIONS2)
    assert (res.n, res.n_missing_reference, res.n_missing_evaluated) == (0, 1, 1)
    np.testing.assert_allclose(res.pairs["t_eval_onset"], rec.pairs["t_eval_onset"])


def test_onset_error_long_region_absent_on_one_side() -> None:
    contacts, tm = _to_long(_traj_a(), "real", "hA")
    extra = _long([("real", "m", "pick", "s1", "A", "hA", 0.5, 0.25, "T3", True)])
    res = onset_error_ms_long(pd.concat([contacts, extra], ignore_index=True), tm, eval_source="real")
    assert res.pairs["region"].tolist() == ["T1", "T3", "P1"]
    row = res.pairs[res.pairs["region"] == "T3"].iloc[0]
    assert math.isnan(row["t_ref_onset"]) and row["t_eval_onset"] == pytest.approx(0.25)
    assert res.n_missing_reference == 1
