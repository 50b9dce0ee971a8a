"""A lake file changed by anything but its stage (the campaign's `COPY ... TO` over a taxels file, a fake
recording dropped into the lake) is found: the catalog refresh refuses naming it, and ingest rebuilds the
recording it belongs to instead of calling it unchanged."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from schemas.vocabulary import RecordingStatus
from touch2robot import catalog
from touch2robot import lake as lake_io
from touch2robot.ingest import ingest_file
from touch2robot.settings import DataLayout


def _zeroed(path: Path) -> None:
    """What `EXPLAIN ANALYZE COPY (SELECT ... 0 ...) TO '<file>'` did: the same columns, zeros."""
    table = pq.read_table(path)
    values = pa.array([[0.0] * 256] * table.num_rows, type=table.schema.field("values").type)
    pq.write_table(table.set_column(table.schema.get_field_index("values"), "values", values), path)


def test_a_changed_stream_file_is_refused_by_the_refresh_and_rebuilt_by_ingest(smoke_data: Path, tmp_path: Path):
    layout = DataLayout(tmp_path / "data")
    glove = tmp_path / "g.mcap"
    shutil.copy(next((smoke_data / "recordings").glob("pick_*_glove.mcap")), glove)
    first = ingest_file(glove, layout.lake)
    catalog.refresh(layout)
    taxels = lake_io.file_path(layout.lake, "taxels", first.recording_id)
    original = pq.read_table(taxels)

    _zeroed(taxels)
    assert lake_io.check(taxels) == "changed since its stage wrote it"
    with pytest.raises(lake_io.LakeFileChanged, match=rf"taxels/{first.recording_id}.parquet: changed"):
        catalog.refresh(layout)

    again = ingest_file(glove, layout.lake)
    assert again.status == RecordingStatus.INGESTED  # not "unchanged": the zeros are gone
    assert pq.read_table(taxels).equals(original)
    catalog.refresh(layout)


def test_a_file_no_stage_wrote_is_refused(replay_data: Path, tmp_path: Path) -> None:
    layout = DataLayout(tmp_path / "data")
    ingest_file(next((replay_data / "recordings").glob("pick_*_calib.mcap")), layout.lake)
    fake = layout.lake / "recordings" / "x.parquet"
    pq.write_table(pq.read_table(lake_io.files(layout.lake, "recordings")[0]), fake)
    with pytest.raises(lake_io.LakeFileChanged, match=r"recordings/x\.parquet: no producer digest"):
        catalog.refresh(layout)
    lake_io.remove(fake)
    catalog.refresh(layout)


def test_a_removed_file_takes_its_digest_along(tmp_path: Path) -> None:
    path = lake_io.write_atomic(pa.table({"x": np.arange(3)}), tmp_path / "t" / "a.parquet")
    assert lake_io.check(path) is None and lake_io.digest_path(path).exists()
    lake_io.remove(path)
    assert not path.exists() and not lake_io.digest_path(path).exists()


def test_a_checked_file_is_hashed_again_only_once_it_changed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every flow checks the whole lake; a file that passed is remembered by its state (inode, size, mtime,
    ctime) and not hashed again while that stays. A rewrite in place at the same size, as a stray
    `COPY ... TO` may make, moves the ctime and is hashed and refused. A state of the last two seconds is never
    remembered: a rewrite within the same timestamp tick would keep it."""
    hashed: list[Path] = []
    sha256 = lake_io._sha256
    monkeypatch.setattr(lake_io, "_sha256", lambda path: hashed.append(path) or sha256(path))
    path = lake_io.write_atomic(pa.table({"x": np.arange(1000.0)}), tmp_path / "t" / "a.parquet")
    hashed.clear()
    assert lake_io.check(path) is None and lake_io.check(path) is None
    assert len(hashed) == 2  # written just now: not settled, hashed every time

    monkeypatch.setattr(lake_io, "SETTLED_NS", 0)
    hashed.clear()
    assert lake_io.check(path) is None and lake_io.check(path) is None
    assert len(hashed) == 1  # settled: the second check trusts the first

    time.sleep(0.05)  # past the timestamp tick of the first write
    data = bytearray(path.read_bytes())
    data[len(data) // 3] ^= 0xFF
    with open(path, "r+b") as f:  # in place: the same inode and size
        f.write(bytes(data))
    assert lake_io.check(path) == "changed since its stage wrote it"
    assert len(hashed) == 2
