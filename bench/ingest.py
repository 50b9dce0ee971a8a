"""Ingestion throughput: MCAP -> Parquet, in MB/s of recording files, next to
(1) the raw `mcap` message iteration of the same files (the limit) and (2) the naive
per-message decode + pandas approach users write first — all measured in this run.

    uv run python bench/ingest.py [--mb 200] [--naive-files 15]

The recordings are generated once by the simulated demonstrator (longer takes via
``pace``) and kept under bench/out/ingest (git-ignored) for later runs.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import pandas as pd
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from touch2robot.ingest import ingest_file
from touch2robot.synth.config import SynthConfig
from touch2robot.synth.generate import RecordingJob, write_recording

OUT = Path(__file__).parent / "out" / "ingest"


def make_set(target_mb: float) -> list[Path]:
    OUT.mkdir(parents=True, exist_ok=True)
    config = SynthConfig(pace=3.0, subjects=50, demos_per_subject=10)
    paths = sorted(OUT.glob("*.mcap"))
    total = sum(p.stat().st_size for p in paths) / 1e6
    demo = 0
    while total < target_mb:
        demo += 1
        for task in config.tasks:
            job = RecordingJob(task, 1 + demo % 50, 1 + demo // 50)
            path = OUT / job.file_name
            if not path.exists():
                write_recording(config, job, OUT, OUT / "groundtruth")
                total += path.stat().st_size / 1e6
        print(f"\rgenerated {total:.0f} MB", end="", flush=True)
    print()
    return sorted(OUT.glob("*.mcap"))


def raw_iteration(paths: list[Path]) -> float:
    t = time.perf_counter()
    n = 0
    for p in paths:
        with open(p, "rb") as f:
            for _ in make_reader(f).iter_messages():
                n += 1
    return time.perf_counter() - t


def project_ingest(paths: list[Path], lake: Path) -> float:
    t = time.perf_counter()
    for p in paths:
        result = ingest_file(p, lake)
        assert result.status == "ingested", result
    return time.perf_counter() - t


def naive_ingest(paths: list[Path], out: Path) -> float:
    """Decode every message with mcap_ros2, append dict rows, build DataFrames, write Parquet."""
    t = time.perf_counter()
    for p in paths:
        rows: dict[str, list[dict]] = {}
        with open(p, "rb") as f:
            for _, channel, message, msg in make_reader(
                f, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages():
                row: dict[str, Any] = {"t": message.log_time / 1e9}
                for field in ("values", "position", "velocity", "effort", "poses"):
                    if hasattr(msg, field):
                        value = getattr(msg, field)
                        row[field] = (
                            [[q.position.x, q.position.y, q.position.z] for q in value]
                            if field == "poses"
                            else list(value)
                        )
                if hasattr(msg, "pose"):
                    pos, ori = msg.pose.position, msg.pose.orientation
                    row.update(px=pos.x, py=pos.y, pz=pos.z, qw=ori.w, qx=ori.x, qy=ori.y, qz=ori.z)
                rows.setdefault(channel.topic, []).append(row)
        for topic, topic_rows in rows.items():
            pd.DataFrame(topic_rows).to_parquet(out / f"{p.stem}_{topic.strip('/').replace('/', '_')}.parquet")
    return time.perf_counter() - t


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--mb", type=float, default=200.0, help="size of the generated recording set")
    parser.add_argument("--naive-files", type=int, default=15, help="files for the (slow) naive baseline")
    args = parser.parse_args()
    paths = make_set(args.mb)
    size = sum(p.stat().st_size for p in paths) / 1e6
    naive_paths = paths[: args.naive_files]
    naive_size = sum(p.stat().st_size for p in naive_paths) / 1e6
    raw_iteration(paths[:5])  # warm the page cache and imports
    with tempfile.TemporaryDirectory() as tmp:
        t_raw = raw_iteration(paths)
        t_proj = project_ingest(paths, Path(tmp) / "lake")
        naive_out = Path(tmp) / "naive"
        naive_out.mkdir()
        t_naive = naive_ingest(naive_paths, naive_out)
        shutil.rmtree(naive_out)
    raw, proj, naive = size / t_raw, size / t_proj, naive_size / t_naive
    print(f"recordings: {len(paths)} files, {size:.0f} MB")
    print(f"raw mcap iteration (limit):    {raw:8.1f} MB/s  ({t_raw:.1f} s)")
    print(f"touch2robot ingest:            {proj:8.1f} MB/s  ({t_proj:.1f} s)")
    print(f"naive decode + pandas ({len(naive_paths)} files): {naive:8.1f} MB/s  ({t_naive:.1f} s)")
    print(f"ratio ingest / limit: {proj / raw:.2f}   (target >= 0.70)")
    print(f"ratio ingest / naive: {proj / naive:.1f}x")


if __name__ == "__main__":
    main()
