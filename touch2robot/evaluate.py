"""Evaluation tables: every evaluated contact source (sim / real / reconstructed, any method)
against the human reference, the user-study statistics, and the figures that show them.

Builds the rows of the lake tables ``contact_metrics``, ``onset_errors`` and ``user_study``
(schemas in ``schemas.tables``) from the long ``contacts`` and ``time_map`` tables and a ratings
CSV, with the scoring rules of :mod:`touch2robot.metrics` and :mod:`touch2robot.stats`.

Roll-ups: a key column holding ``'*'`` (:data:`touch2robot.metrics.ALL`, the same label as the
SQL ``contact_score_slices`` macro) is summed over that dimension, e.g. ``task = '*' AND
region = '*'`` is a method's overall score. Undefined ratios (0/0) are stored as NULL.

No orchestration (Prefect) imports: the flow ``evaluate`` wraps these functions.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from schemas.tables import PARTITIONS, ROBOT_REGIONS, SCHEMAS, unseeded
from schemas.vocabulary import Origin, RecordingKind, RecordingStatus, Source
from touch2robot import lake as lake_io
from touch2robot.comparison.statistics import CLUSTER_COLUMNS
from touch2robot.contacts import long_rows
from touch2robot.datasets import LAKE, folder_digest
from touch2robot.datasets import safe_file_id as file_id
from touch2robot.ingest import recording_rows
from touch2robot.metrics import ALL, COUNT_COLUMNS, contact_counts_long, contact_scores_table, onset_error_ms_long
from touch2robot.stats import CONDITIONS, QUESTIONS, user_study

if TYPE_CHECKING:
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

__all__ = [
    "ALL",
    "CLUSTER_TABLE_COLUMNS",
    "CONTACT_COLUMNS",
    "FIDELITY_REFERENCE",
    "FIDELITY_SOURCE",
    "REFERENCE_SOURCE",
    "ablation_sums",
    "contact_metrics_table",
    "demonstration_sums",
    "evaluated_sources",
    "fidelity_contacts",
    "fidelity_replays",
    "file_id",
    "folder_digest",
    "heldout_demonstration_sums",
    "is_synthetic",
    "onset_errors_table",
    "per_seed",
    "plot_metrics_by_method",
    "plot_ratings",
    "plot_timeline",
    "pool_seeds",
    "pooled_as",
    "ratings_files",
    "read_contacts",
    "read_time_map",
    "replace_table",
    "replay_demonstrations",
    "reported_studies",
    "source_folders",
    "user_study_table",
]

REFERENCE_SOURCE = Source.HUMAN
"""The contact source every other source is scored against (the glove's tactile preference)."""

# The contacts columns the evaluation reads (`value` is not needed and is the widest column).
CONTACT_COLUMNS: tuple[str, ...] = (
    "source",
    "method",
    "task",
    "subject",
    "sequence_id",
    "reference_id",
    "t",
    "t_ref",
    "region",
    "contact",
    "seed",
)

# Roll-ups written per (source, method): the cube over task x region, like the SQL macro.
_SLICES: tuple[tuple[str, ...], ...] = (
    ("method", "task", "region"),
    ("method", "task"),
    ("method", "region"),
    ("method",),
)
_ONSET_COUNTS: tuple[str, ...] = ("n_pairs", "n", "n_missing_reference", "n_missing_evaluated", "n_missing_both")


# --------------------------------------------------------------------------- reading the lake


def _contacts_partitioning() -> ds.Partitioning:
    keys = PARTITIONS["contacts"]
    return ds.partitioning(pa.schema([SCHEMAS["contacts"].field(k) for k in keys]), flavor="hive")


def evaluated_sources(lake: Path, reference: str = REFERENCE_SOURCE) -> list[str]:
    """Contact sources present in the lake other than the reference, sorted.

    Read from the ``source=`` partition folders of ``contacts`` (holding at least one file),
    so new sources written by later stages are picked up without any list to maintain.
    """
    root = lake / "contacts"
    if not root.is_dir():
        return []
    found = []
    for folder in root.glob("source=*"):
        name = folder.name.split("=", 1)[1]
        if name != reference and folder.is_dir() and any(not p.name.startswith(".") for p in folder.rglob("*.parquet")):
            found.append(name)
    return sorted(found)


def source_folders(lake: Path, source: str, reference: str = REFERENCE_SOURCE) -> list[Path]:
    """The lake folders one source's evaluation reads: its contacts, the reference's, the time maps."""
    return [lake / "contacts" / f"source={reference}", lake / "contacts" / f"source={source}", lake / "time_map"]


def read_contacts(lake: Path, sources: Sequence[str], task: str | None = None) -> pd.DataFrame:
    """The ``contacts`` rows of ``sources`` (optionally one task), columns :data:`CONTACT_COLUMNS`.

    Reads the Parquet files directly (hive partitions, hidden temporary files skipped), so the
    evaluation does not depend on the catalog having been refreshed.
    """
    schema = SCHEMAS["contacts"]
    root = lake / "contacts"
    if not lake_io.files(lake, "contacts"):
        return pa.schema([schema.field(c) for c in CONTACT_COLUMNS]).empty_table().to_pandas()
    dataset = ds.dataset(root, format="parquet", partitioning=_contacts_partitioning(), schema=schema)
    where = pc.field("source").isin(list(sources))
    if task is not None:
        where = where & (pc.field("task") == task)
    return dataset.to_table(columns=list(CONTACT_COLUMNS), filter=where).to_pandas()


def per_seed(contacts: pd.DataFrame, reference: str = REFERENCE_SOURCE) -> list[tuple[int, pd.DataFrame]]:
    """``contacts`` split by sweep seed: per seed of the evaluated rows, the reference's rows (the glove's have
    no seed: every seed is scored against them) and that seed's evaluated rows. A row with no seed (a replay
    recorded without one) counts as seed 0."""
    is_reference = contacts["source"] == reference
    evaluated = contacts[~is_reference]
    of_seed = evaluated["seed"].fillna(0).astype(np.int64)
    return [
        (int(seed), pd.concat([contacts[is_reference], part], ignore_index=True))
        for seed, part in evaluated.groupby(of_seed, sort=True)
    ]


def read_time_map(lake: Path) -> pd.DataFrame:
    """Every replay's recorded time map (columns recording_id, t, t_ref)."""
    schema = SCHEMAS["time_map"]
    if not lake_io.files(lake, "time_map"):
        return schema.empty_table().to_pandas()
    return ds.dataset(lake / "time_map", format="parquet", schema=schema).to_table().to_pandas()


# --------------------------------------------------------------------------- contact metrics


def _fill_all(frame: pd.DataFrame, columns: Iterable[str]) -> pd.DataFrame:
    """Add the rolled-up key columns that ``frame`` lacks, holding ALL."""
    return frame.assign(**{c: ALL for c in columns if c not in frame.columns})


def contact_metrics_table(contacts: pd.DataFrame, eval_source: str, reference: str = REFERENCE_SOURCE) -> pd.DataFrame:
    """Rows of ``contact_metrics`` for one evaluated source: per method x task x region and roll-ups.

    Counts come from :func:`touch2robot.metrics.contact_counts_long` (the alignment rule and
    the SQL twin are documented there), summed over subjects, then over regions and/or tasks
    for the ``'*'`` rows. ``n_sequences`` counts the source's sequences of that method (and task).

    Args:
        contacts: long contacts rows holding at least the reference and ``eval_source``.
        eval_source: the source scored, e.g. ``"real"``.
        reference: the reference source.

    Returns:
        Columns as ``schemas.tables.contact_metrics`` but its ``seed`` (the caller's), sorted by method,
        task, region; empty when nothing of ``eval_source`` aligns with the reference.
    """
    names = unseeded("contact_metrics").names
    counts = contact_counts_long(contacts, ref_source=reference, eval_source=eval_source)
    if counts.empty:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in names})
    ev = contacts[contacts["source"] == eval_source]
    per_task = ev.groupby(["method", "task"])["sequence_id"].nunique().rename("n_sequences").reset_index()
    per_method = _fill_all(ev.groupby("method")["sequence_id"].nunique().rename("n_sequences").reset_index(), ["task"])
    n_sequences = pd.concat([per_task, per_method], ignore_index=True)
    parts = [_fill_all(contact_scores_table(counts, by=by), ("task", "region")) for by in _SLICES]
    table = pd.concat(parts, ignore_index=True).merge(n_sequences, on=["method", "task"], how="left")
    table = table.assign(
        source=eval_source,
        reference_source=reference,
        n=table[list(COUNT_COLUMNS)].sum(axis=1),
        n_sequences=table["n_sequences"].fillna(0).astype(np.int64),
    )
    return table.sort_values(["method", "task", "region"], ignore_index=True)[names]


def pool_seeds(metrics: pd.DataFrame, onset_summaries: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``contact_metrics`` rows and ``onset_errors`` summary rows with the sweep seeds pooled (counts summed,
    ratios recomputed from them; E weighted by each seed's valid pairs), ``seed`` NULL: the overall figures
    of a figure or summary that shows one bar per method."""
    keys = ["reference_source", "source", "method", "task", "region"]
    sizes = metrics.groupby(keys, as_index=False, sort=True)[["n_sequences", "n"]].sum()
    m = contact_scores_table(metrics, by=keys).merge(sizes, on=keys).assign(seed=None)
    o = onset_summaries[onset_summaries["sequence_id"] == ALL]
    o = o.assign(error_sum=o["error_ms"].fillna(0.0) * o["n"])
    same = [*keys, "sequence_id", "subject", "reference_id"]
    o = o.groupby(same, as_index=False, sort=True)[[*_ONSET_COUNTS, "error_sum"]].sum()
    o = o.assign(error_ms=np.where(o["n"] > 0, o["error_sum"] / o["n"].where(o["n"] > 0, 1), np.nan), seed=None)
    return m[metrics.columns], o.drop(columns="error_sum").reindex(columns=onset_summaries.columns)


# --------------------------------------------------------------------------- tactile fidelity

FIDELITY_REFERENCE = Source.REAL
"""The reference of tactile fidelity: the contacts measured when a method's trajectory is replayed on the robot."""


def fidelity_replays(lake: Path) -> pd.DataFrame:
    """The ingested robot replays that name the trajectory they executed (recording_id, method, task, subject,
    trajectory, seed: NULL read as 0): the pairs tactile fidelity scores. A replay that does not name one has
    nothing to score."""
    rows = recording_rows(lake).to_pandas()
    keep = (rows["status"] == RecordingStatus.INGESTED) & (rows["kind"] == RecordingKind.ROBOT_REPLAY)
    rows = rows[keep & rows["trajectory"].notna() & (rows["trajectory"] != "")]
    rows = rows.assign(seed=rows["seed"].fillna(0).astype(np.int64))
    return rows[["recording_id", "method", "task", "subject", "trajectory", "seed"]].reset_index(drop=True)


def fidelity_contacts(lake: Path, contact_threshold_n: float) -> pd.DataFrame:
    """Long contacts rows for tactile fidelity, keyed by replay: per robot replay naming its trajectory, the
    contacts measured on it (source ``real``) and those its trajectory (the rollout of that id of the replay's
    sweep seed) makes on the target hand in simulation (the ``rollouts`` row's region force >
    ``contact_threshold_n``, the sim contacts' rule; source ``sim`` for a teacher's or the kinematic trajectory,
    ``reconstructed`` for the student's). Both sides carry the replay as ``sequence_id`` and ``reference_id``
    and its seed, so a trajectory replayed twice is scored twice. The measured side keeps the first sample of
    each run of equal ``t_ref`` (before the first command and after the last one the replay's clock holds), so
    that it is a strictly increasing reference timeline."""
    names = list(CONTACT_COLUMNS)
    replays = fidelity_replays(lake)
    if replays.empty:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in names})
    real = read_contacts(lake, [FIDELITY_REFERENCE])
    real = real[real["sequence_id"].isin(set(replays["recording_id"]))].sort_values(["sequence_id", "region", "t"])
    real = real.drop_duplicates(["sequence_id", "region", "t_ref"]).assign(reference_id=lambda f: f["sequence_id"])
    real = real.assign(seed=real["sequence_id"].map(dict(zip(replays["recording_id"], replays["seed"], strict=True))))
    wanted = set(replays["trajectory"])
    columns = ["rollout_id", "origin", "seed", "t", "t_ref", "region_force"]
    tables = [pq.read_table(f, columns=columns) for f in lake_io.files(lake, "rollouts")]
    tables = [t.filter(pc.field("rollout_id").isin(sorted(wanted))) for t in tables]
    parts = [real]
    if tables:
        rollouts = pa.concat_tables(tables).to_pandas()
        by_id = {key: g for key, g in rollouts.groupby(["rollout_id", "seed"], sort=False)}
        for replay in replays.to_dict("records"):
            rows = by_id.get((replay["trajectory"], replay["seed"]))
            if rows is None:
                continue
            force = np.stack(rows["region_force"].to_numpy())
            origin = rows["origin"].iloc[0]
            simulated = long_rows(
                source=Source.RECONSTRUCTED if origin == Origin.STUDENT else Source.SIM,
                method=str(replay["method"]),
                task=str(replay["task"]),
                subject=str(replay["subject"]),
                sequence_id=str(replay["recording_id"]),
                reference_id=str(replay["recording_id"]),
                t=rows["t"].to_numpy(),
                t_ref=rows["t_ref"].to_numpy(),
                regions=ROBOT_REGIONS,
                contact=force > contact_threshold_n,
                value=force,
            ).to_pandas()
            parts.append(simulated.assign(seed=replay["seed"])[names])
    return pd.concat(parts, ignore_index=True)[names]


# --------------------------------------------------------------------------- onset errors


def onset_errors_table(
    contacts: pd.DataFrame, time_map: pd.DataFrame, eval_source: str, reference: str = REFERENCE_SOURCE
) -> pd.DataFrame:
    """Rows of ``onset_errors`` for one evaluated source: one per trajectory-region pair plus summaries.

    Pairs come from :func:`touch2robot.metrics.onset_error_ms_long`; a sequence with a recorded
    time map (a real replay) has its onsets mapped through it, any other (a rollout already on
    the reference clock) uses its stored ``t_ref`` (``via_time_map`` says which). A pair row has
    ``n_pairs = 1``, its onsets, ``error_ms`` = |t_eval - t_ref| in ms and ``valid``. Summary rows
    (``sequence_id = subject = reference_id = '*'``) per method x task [x region] and roll-ups
    carry E = 1000/N * sum |t_eval - t_ref| over their valid pairs in ``error_ms`` (NULL when
    N = 0), N in ``n`` and the missing-onset counts; their onset and flag columns are NULL.

    Returns:
        Columns as ``schemas.tables.onset_errors`` but its ``seed`` (the caller's): pair rows sorted by
        method, task, sequence, region order, then the summaries; empty when ``eval_source`` has no rows.
    """
    names = unseeded("onset_errors").names
    if not (contacts["source"] == eval_source).any():
        return pd.DataFrame({c: pd.Series(dtype=object) for c in names})
    result = onset_error_ms_long(
        contacts, time_map, eval_source=eval_source, ref_source=reference, on_missing_time_map="use_t_ref"
    )
    pairs = result.pairs.rename(columns={"trajectory": "sequence_id"})
    miss_ref = pairs["t_ref_onset"].isna()
    miss_ev = pairs["t_eval_onset"].isna()
    pairs = pairs.assign(
        via_time_map=pairs["sequence_id"].isin(set(time_map["recording_id"])),
        n_pairs=1,
        n=pairs["valid"].astype(np.int64),
        n_missing_reference=miss_ref.astype(np.int64),
        n_missing_evaluated=miss_ev.astype(np.int64),
        n_missing_both=(miss_ref & miss_ev).astype(np.int64),
    )
    region_order = {r: k for k, r in enumerate(ROBOT_REGIONS)}
    pairs = pairs.sort_values(
        ["method", "task", "sequence_id", "region"],
        key=lambda s: s.map(region_order).fillna(len(region_order)) if s.name == "region" else s,
        ignore_index=True,
    )
    # E over a summary = total absolute error of its valid pairs / their number, recomputed from
    # the pair errors so every roll-up agrees with the pairs it summarises.
    err = pairs.assign(error_sum=pairs["error_ms"].where(pairs["valid"], 0.0))
    summaries = []
    for by in _SLICES:
        s = err.groupby(list(by), sort=True)[[*_ONSET_COUNTS, "error_sum"]].sum().reset_index()
        s["error_ms"] = np.where(s["n"] > 0, s["error_sum"] / s["n"].where(s["n"] > 0, 1), np.nan)
        summaries.append(
            _fill_all(s.drop(columns="error_sum"), ("task", "region", "sequence_id", "subject", "reference_id"))
        )
    table = pd.concat([pairs, *summaries], ignore_index=True).assign(source=eval_source, reference_source=reference)
    return table[names]


# --------------------------------------------------------------------------- the comparison's clusters

DEMONSTRATION_KEYS: tuple[str, ...] = ("method", "task", "reference_id")
CLUSTER_TABLE_COLUMNS: tuple[str, ...] = (
    "reference_source",
    "source",
    "method",
    "task",
    "demonstration",
    *CLUSTER_COLUMNS,
)


def replay_demonstrations(lake: Path) -> dict[str, str]:
    """Each ingested robot replay's glove demonstration (replay recording_id -> the glove recording its
    trajectory followed, as the ``real`` contacts name it): tactile fidelity's rows are keyed by replay."""
    if not lake_io.files(lake, "contacts"):
        return {}
    schema = SCHEMAS["contacts"]
    dataset = ds.dataset(lake / "contacts", format="parquet", partitioning=_contacts_partitioning(), schema=schema)
    table = dataset.to_table(columns=["sequence_id", "reference_id"], filter=pc.field("source") == Source.REAL)
    pairs = table.group_by(["sequence_id", "reference_id"]).aggregate([])
    return dict(zip(pairs["sequence_id"].to_pylist(), pairs["reference_id"].to_pylist(), strict=True))


def demonstration_sums(
    contacts: pd.DataFrame,
    onsets: pd.DataFrame,
    eval_source: str,
    reference: str = REFERENCE_SOURCE,
    demonstration_of: dict[str, str] | None = None,
) -> pd.DataFrame:
    """The clusters of the method comparison (:mod:`touch2robot.comparison.statistics`): per method x task x
    demonstration, TP/FP/FN/TN over its regions and evaluated sequences, and the sum of its valid onset
    errors (ms) with their number, from the long ``contacts`` and the ``onset_errors`` rows of ``eval_source``.

    ``demonstration_of`` maps a ``reference_id`` to the human demonstration it stands for (tactile
    fidelity scores per replay: a replay -> its glove session); by default the reference is the
    demonstration. Several sequences of one demonstration (rollouts, replays) pool into its cluster.
    """
    names = list(CLUSTER_TABLE_COLUMNS)
    counts = contact_counts_long(contacts, ref_source=reference, eval_source=eval_source, keys=DEMONSTRATION_KEYS)
    pairs = onsets[(onsets["source"] == eval_source) & (onsets["reference_source"] == reference)]
    pairs = pairs[pairs["sequence_id"] != ALL]  # the pair rows, not the summaries
    valid = pairs["valid"].eq(True)
    onset = (
        pairs.assign(onset_error_sum_ms=pairs["error_ms"].where(valid, 0.0), onset_pairs=valid.astype(np.int64))
        .groupby(list(DEMONSTRATION_KEYS), as_index=False)[["onset_error_sum_ms", "onset_pairs"]]
        .sum()
    )
    sums = counts.merge(onset, on=list(DEMONSTRATION_KEYS), how="outer")
    if sums.empty:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in names})
    sums[list(CLUSTER_COLUMNS)] = sums[list(CLUSTER_COLUMNS)].fillna(0)
    mapping = demonstration_of or {}
    sums["demonstration"] = [mapping.get(r, r) for r in sums["reference_id"]]
    sums = sums.groupby(["method", "task", "demonstration"], as_index=False, sort=True)[list(CLUSTER_COLUMNS)].sum()
    return sums.assign(reference_source=reference, source=eval_source)[names]


def heldout_demonstration_sums(
    lake: Path, task: str, held_out: Sequence[str], reconstructed: pd.DataFrame
) -> pd.DataFrame:
    """A student variant's reconstructed contacts (long rows, source reconstructed) vs the human's, summed per
    held-out demonstration (task, demonstration and :data:`CLUSTER_COLUMNS`), scored as the evaluation scores
    the full model's (:func:`demonstration_sums`)."""
    human = read_contacts(lake, [Source.HUMAN], task=task)
    scored = pd.concat(
        [human[human["reference_id"].isin(list(held_out))], reconstructed.reindex(columns=list(CONTACT_COLUMNS))],
        ignore_index=True,
    )
    no_time_map = SCHEMAS["time_map"].empty_table().to_pandas()  # a reconstruction carries t_ref already
    onsets = onset_errors_table(scored, no_time_map, Source.RECONSTRUCTED)
    sums = demonstration_sums(scored, onsets, Source.RECONSTRUCTED)
    return sums.drop(columns=["reference_source", "source", "method"])


def ablation_sums(lake: Path) -> pd.DataFrame:
    """The student ablations' demonstration sums (table ``student_variants``, the full model's left out: its
    reconstructions are in ``contacts``) as comparison clusters of preference alignment, source reconstructed."""
    names = [*CLUSTER_TABLE_COLUMNS, "variant", "seed"]
    files = lake_io.files(lake, "student_variants")
    if not files:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in names})
    rows = pa.concat_tables([pq.read_table(f, schema=SCHEMAS["student_variants"]) for f in files]).to_pandas()
    rows = rows[rows["variant"] != "full"]
    return rows.assign(reference_source=REFERENCE_SOURCE, source=Source.RECONSTRUCTED)[names]


FIDELITY_SOURCE = Source.SIM
"""The source tactile fidelity's comparison rows carry: every replayed trajectory's contacts come from simulation
(a student's reconstruction is a simulated trajectory too), so the methods pair on one footing whatever made them."""


def pooled_as(sums: pd.DataFrame, source: str) -> pd.DataFrame:
    """Demonstration sums of several evaluated sources as one (their sums added per method x task x
    demonstration x seed): tactile fidelity compares a student's and a teacher's trajectories alike."""
    keys = ["reference_source", "method", "task", "demonstration", "seed"]
    pooled = sums.groupby(keys, as_index=False, sort=True)[list(CLUSTER_COLUMNS)].sum()
    return pooled.assign(source=source)[[*CLUSTER_TABLE_COLUMNS, "seed"]]


# --------------------------------------------------------------------------- user study


def ratings_files(location: Path) -> list[Path]:
    """The ratings CSV files at ``location``: the file itself, or every visible ``*.csv`` in the folder."""
    if location.is_file():
        return [location]
    if not location.is_dir():
        return []
    return sorted(p for p in location.glob("*.csv") if not p.name.startswith("."))


def reported_studies(studies: list[dict]) -> list[dict]:
    """The ratings files whose statistics are reported (each a dict with ``synthetic`` and ``rows``): SYNTHETIC
    ones only while no real ratings file has statistics, so a study's own ratings replace the demonstrator's
    example instead of standing beside it."""
    if any(s["rows"] and not s["synthetic"] for s in studies):
        return [s for s in studies if not s["synthetic"]]
    return studies


def is_synthetic(ratings: pd.DataFrame, name: str) -> bool:
    """Whether ratings are SYNTHETIC: the file name says so or any row's ``synthetic`` flag is set.

    Either mark suffices: one synthetic row makes every statistic of the file synthetic.
    """
    if "synthetic" in name.lower():
        return True
    if "synthetic" not in ratings.columns:
        return False
    flags = ratings["synthetic"].astype(str).str.strip().str.lower()
    return bool(flags.isin(("true", "1", "yes")).any())


def user_study_table(ratings: pd.DataFrame, ratings_file: str, ratings_sha256: str, synthetic: bool) -> pd.DataFrame:
    """Rows of ``user_study``: one per question, from :func:`touch2robot.stats.user_study`.

    Medians and IQRs per condition (Visual Feedback vs Touch2Robot), the paired two-sided
    Wilcoxon statistic and p, Holm-adjusted p across the questions, and the exact scipy settings
    (``zero_method``, ``method``, ``correction``) so the numbers can be reproduced.

    Raises:
        ValueError: ratings that :func:`touch2robot.stats.user_study` rejects (the message names
            the participant and question).
    """
    result = user_study(ratings)
    table = result.to_frame().assign(
        ratings_file=ratings_file,
        ratings_sha256=ratings_sha256,
        zero_method=result.zero_method,
        method=result.method,
        correction=result.correction,
        synthetic=synthetic,
    )
    return table[SCHEMAS["user_study"].names]


# --------------------------------------------------------------------------- writing


def replace_table(lake: Path, table: str, rows: pd.DataFrame, keys: Sequence[str]) -> list[str]:
    """Make ``rows`` the whole content of an evaluation table: one file per ``keys`` group.

    Each file is written atomically (:func:`touch2robot.lake.write_rows`), re-writing a key
    replaces its file, and files of keys no longer present (a method whose contacts were
    removed, a deleted ratings file) are removed afterwards, so a re-run never duplicates rows
    and never keeps stale ones. Only for tables that the evaluation alone writes.

    Returns:
        The file ids written, sorted.
    """
    schema = SCHEMAS[table]
    written = []
    for key, group in rows.groupby(list(keys), sort=True) if len(rows) else []:
        fid = LAKE[table].file_id([str(k) for k in (key if isinstance(key, tuple) else (key,))], {})
        rows_arrow = pa.Table.from_pandas(group, schema=schema, preserve_index=False).replace_schema_metadata()
        lake_io.write_rows(lake, table, fid, rows_arrow)
        written.append(fid)
    keep = {f"{fid}.parquet" for fid in written}
    for path in lake_io.files(lake, table):
        if path.name not in keep:
            lake_io.remove(path)
    return sorted(written)


# --------------------------------------------------------------------------- figures


def _figure(width: float, height: float) -> Figure:
    # An object-oriented Figure (Agg canvas, no pyplot state): safe in worker threads.
    # matplotlib is imported only when a figure is drawn: the tables need none of it.
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained")


def plot_timeline(reference: pd.DataFrame, evaluated: pd.DataFrame, title: str, path: Path) -> Path:
    """Per-region contact timeline of one evaluated sequence over its reference, on the reference clock.

    Each region row shows the reference (upper band) and the evaluated sequence (lower band);
    both take ``t_ref`` and ``contact`` columns of the long contacts table.
    """
    fig = _figure(10, 3.6)
    ax = fig.add_subplot()
    for k, region in enumerate(ROBOT_REGIONS):
        for frame, lo, color in ((reference, k + 0.5, "C0"), (evaluated, k + 0.1, "C1")):
            r = frame[frame["region"] == region].sort_values("t_ref")
            ax.fill_between(
                r["t_ref"], lo, lo + 0.4 * r["contact"].astype(float), step="post", color=color, linewidth=0
            )
    ax.set_yticks(np.arange(len(ROBOT_REGIONS)) + 0.5, ROBOT_REGIONS)
    ax.set_ylim(0, len(ROBOT_REGIONS))
    ax.set_xlabel("reference time (s)")
    ax.legend(
        handles=[_patch("C0", "reference (upper)"), _patch("C1", "evaluated (lower)")], loc="upper right", fontsize=7
    )
    ax.set_title(title, fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    return path


def _patch(color: str, label: str) -> Patch:
    from matplotlib.patches import Patch

    return Patch(color=color, label=label)


def plot_metrics_by_method(metrics: pd.DataFrame, onsets: pd.DataFrame, path: Path) -> Path:
    """Bar chart of precision, recall, F1, FPR and onset error per task, one bar per source/method.

    Takes the ``region = '*'`` rows of ``contact_metrics`` and the summary rows
    (``sequence_id = region = '*'``) of ``onset_errors``; task ``'*'`` is drawn as "all".
    """
    m = metrics[metrics["region"] == ALL]
    o = onsets[(onsets["sequence_id"] == ALL) & (onsets["region"] == ALL)]
    keys = ["source", "method", "task"]
    table = m[[*keys, "precision", "recall", "f1", "fpr"]].merge(
        o[[*keys, "error_ms"]].rename(columns={"error_ms": "onset_error_ms"}), on=keys, how="outer"
    )
    tasks = sorted(t for t in table["task"].unique() if t != ALL) + ([ALL] if (table["task"] == ALL).any() else [])
    groups = sorted({(s, me) for s, me in zip(table["source"], table["method"], strict=True)})
    panels = (
        ("precision", "precision"),
        ("recall", "recall"),
        ("f1", "F1"),
        ("fpr", "FPR"),
        ("onset_error_ms", "onset error E (ms)"),
    )
    fig = _figure(3.2 * len(panels), 3.4)
    axes = fig.subplots(1, len(panels))
    width = 0.8 / max(len(groups), 1)
    x = np.arange(len(tasks))
    for ax, (column, label) in zip(axes, panels, strict=True):
        for g, (source, method) in enumerate(groups):
            rows = table[(table["source"] == source) & (table["method"] == method)].set_index("task")
            values = [float(rows[column].get(t, np.nan)) for t in tasks]
            ax.bar(x + (g - (len(groups) - 1) / 2) * width, values, width, label=f"{source}/{method}", color=f"C{g}")
        ax.set_xticks(x, ["all" if t == ALL else t for t in tasks], fontsize=8)
        ax.set_title(label, fontsize=9)
        if column != "onset_error_ms":
            ax.set_ylim(0, 1.05)
    fig.legend(handles=axes[0].get_legend_handles_labels()[0], fontsize=7, loc="outside right upper")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    return path


def plot_ratings(ratings: pd.DataFrame, title: str, path: Path) -> Path:
    """Box plots of the 7-point ratings per question, the two conditions side by side."""
    fig = _figure(7, 3.4)
    ax = fig.add_subplot()
    questions = [q for q in QUESTIONS if q in set(ratings["question"])]
    for c, condition in enumerate(CONDITIONS):
        data = [
            ratings[(ratings["question"] == q) & (ratings["condition"] == condition)]["rating"].to_numpy(dtype=float)
            for q in questions
        ]
        positions = np.arange(len(questions)) * 3 + c
        box = ax.boxplot(data, positions=positions, widths=0.8, patch_artist=True)
        for patch in box["boxes"]:
            patch.set_facecolor(f"C{c}")
    ax.set_xticks(np.arange(len(questions)) * 3 + 0.5, questions)
    ax.set_ylim(0.5, 7.5)
    ax.set_ylabel("rating (1-7)")
    ax.legend(handles=[_patch(f"C{c}", name) for c, name in enumerate(CONDITIONS)], fontsize=7, loc="lower right")
    ax.set_title(title, fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    return path
