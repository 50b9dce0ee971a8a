"""Ingestion: recordings (MCAP files, rosbag2 folders) -> Parquet stream tables + a ``recordings`` row per
recording.

A file is ingested whole or quarantined whole: it is read and validated completely
before anything is written, its stream tables are written first and its ``recordings``
row last (the commit marker), each file atomically. Re-ingesting an unchanged file
writes nothing; a changed file gets a new id (content hash)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from schemas.messages import STREAMS_BY_KIND
from schemas.rig import Rig
from schemas.vocabulary import RecordingKind, RecordingStatus
from touch2robot import lake as lake_io
from touch2robot.ingest.reader import DecodedRecording, RecordingError, content_id, counts_json, read_recording
from touch2robot.ingest.sources import content_size, recording_digest
from touch2robot.ingest.tables import stream_tables

__all__ = [
    "IngestResult",
    "RecordingError",
    "ReplayLink",
    "ingest_file",
    "link_replays",
    "read_recording",
    "recording_digest",
    "recording_rows",
    "superseded_ids",
]


@dataclass(frozen=True)
class IngestResult:
    recording_id: str
    path: str
    status: RecordingStatus
    reason: str
    kind: str
    rows: int


def _row(path: Path, recording_id: str, size: int, status: str, reason: str, rec: DecodedRecording | None) -> pa.Table:
    meta = rec.metadata if rec else {}
    duration = (rec.end_ns - rec.start_ns) / 1e9 if rec else None
    return pa.table(
        {
            "recording_id": [recording_id],
            "path": [str(path)],
            "file_name": [path.name],
            "size_bytes": [size],
            "kind": [meta.get("kind")],
            "task": [meta.get("task")],
            "subject": [meta.get("subject")],
            "method": [meta.get("method")],
            "reference_recording": [meta.get("reference_recording")],
            "calibration_recording": [meta.get("calibration_recording")],
            "trajectory": [meta.get("trajectory") or None],
            "rig": [rec.rig.name if rec else None],
            "rig_definition": [rec.rig.model_dump_json() if rec else None],
            "seed": pa.array([int(meta["seed"]) if meta.get("seed") else None], pa.int64()),
            "start_time_s": [rec.start_ns / 1e9 if rec else None],
            "end_time_s": [rec.end_ns / 1e9 if rec else None],
            "duration_s": [duration],
            "message_counts": [counts_json(rec.message_counts) if rec else None],
            "status": [status],
            "reason": [reason],
            "ingested_at": [datetime.now(UTC)],
        }
    )


def ingest_file(
    path: Path, lake: Path, session: Mapping[str, str] | None = None, rigs: Mapping[str, Rig] | None = None
) -> IngestResult:
    """Ingest one recording (an MCAP file or a rosbag2 folder) into the lake, or quarantine it with the
    reason. ``session``: fields given on the command line where the recording's own sources lack them;
    ``rigs``: the rigs by name (``touch2robot.ingest.rigs.find_rigs``)."""
    path = Path(path).resolve()
    try:
        rec = read_recording(path, session, rigs)
    except RecordingError as e:
        try:
            rid, size = recording_digest(path)[:16], content_size(path)
        except OSError:  # unreadable: its own quarantine row, keyed by where it is
            rid, size = content_id(f"unreadable:{path}".encode()), 0
        lake_io.remove_id(lake, rid)  # a bad file never leaves rows behind
        lake_io.write_rows(lake, "recordings", rid, _row(path, rid, size, RecordingStatus.QUARANTINED, e.reason, None))
        return IngestResult(rid, str(path), RecordingStatus.QUARANTINED, e.reason, "", 0)
    marker = lake_io.file_path(lake, "recordings", rec.recording_id)
    if _stored_whole(lake, rec, marker):
        _follow_move(lake, marker, path)
        return IngestResult(rec.recording_id, str(path), RecordingStatus.UNCHANGED, "", rec.kind, 0)
    rows = 0
    for table, rows_table in stream_tables(rec).items():
        lake_io.write_rows(lake, table, rec.recording_id, rows_table)
        rows += rows_table.num_rows
    lake_io.write_rows(
        lake,
        "recordings",
        rec.recording_id,
        _row(path, rec.recording_id, rec.size_bytes, RecordingStatus.INGESTED, "", rec),
    )
    return IngestResult(rec.recording_id, str(path), RecordingStatus.INGESTED, "", rec.kind, rows)


def _follow_move(lake: Path, marker: Path, path: Path) -> None:
    """An unchanged recording found at another path (a copied or moved data folder) has its row say where it
    is now: replays link to their calibration and glove session by folder."""
    from schemas.tables import recordings

    row = pq.read_table(marker, schema=recordings)  # a lake of an older schema lacks its newer columns
    if row["path"][0].as_py() == str(path):
        return
    row = row.set_column(row.schema.get_field_index("path"), "path", pa.array([str(path)]))
    row = row.set_column(row.schema.get_field_index("file_name"), "file_name", pa.array([path.name]))
    lake_io.write_rows(lake, "recordings", marker.stem, row)


def _stored_whole(lake: Path, rec: DecodedRecording, marker: Path) -> bool:
    """The recording was ingested and every file of it still matches what ingest wrote (a file
    changed since, say overwritten with zeros, makes it ingested again)."""
    if (
        lake_io.check(marker)
        or pq.read_table(marker, columns=["status"])["status"][0].as_py() != RecordingStatus.INGESTED
    ):
        return False
    streams = STREAMS_BY_KIND[rec.kind]
    return not any(lake_io.check(lake_io.file_path(lake, table, rec.recording_id)) for table in streams)


def recording_rows(lake: Path) -> pa.Table:
    """All rows of the ``recordings`` table (empty table with the schema if none)."""
    from schemas.tables import recordings

    paths = lake_io.files(lake, "recordings")
    if not paths:
        return recordings.empty_table()
    return pa.concat_tables([lake_io.read_rows(p, recordings) for p in paths])


def superseded_ids(lake: Path, current: dict[str, str]) -> list[str]:
    """Ids of earlier versions of files whose content changed: ``current`` maps each
    ingested path to its present id; any other id recorded for the same path is stale."""
    table = recording_rows(lake).to_pydict()
    return sorted(
        {rid for rid, p in zip(table["recording_id"], table["path"], strict=True) if p in current and current[p] != rid}
    )


@dataclass(frozen=True)
class ReplayLink:
    """A replay with the calibration and glove session it names: by file name, in the replay's own folder
    (two sessions' folders may hold files of the same name)."""

    replay: dict
    calibration_id: str
    reference: dict | None


def link_replays(rows: list[dict]) -> tuple[list[dict], list[ReplayLink], list[str]]:
    """Split ingested recordings into glove sessions and replays linked to their
    calibration and reference; returns (gloves, links, problems) where a replay whose
    calibration is missing is left out with a problem line (its reference may be absent:
    then its contacts have no reference_id)."""
    ok = [r for r in rows if r["status"] == RecordingStatus.INGESTED]
    by_place = {(str(Path(r["path"]).parent), r["file_name"]): r for r in ok}
    gloves = [r for r in ok if r["kind"] == RecordingKind.GLOVE_SESSION]
    links, problems = [], []
    for r in ok:
        if r["kind"] != RecordingKind.ROBOT_REPLAY:
            continue
        folder = str(Path(r["path"]).parent)
        calib = by_place.get((folder, r["calibration_recording"]))
        if calib is None or calib["kind"] != RecordingKind.ROBOT_CALIBRATION:
            problems.append(
                f"{r['file_name']}: calibration {r['calibration_recording']!r} is not ingested; no real contacts"
            )
            continue
        links.append(ReplayLink(r, calib["recording_id"], by_place.get((folder, r["reference_recording"]))))
    return gloves, links, problems
