"""Contacts from the lake: one glove session -> human contacts + thresholds; one robot
replay (with its calibration and reference session) -> real contacts + thresholds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from schemas.rig import DEFAULT_RIG, Rig
from schemas.tables import HUMAN_REGIONS, ROBOT_REGIONS
from schemas.vocabulary import Source
from touch2robot import lake as lake_io
from touch2robot.contacts import (
    ContactsConfig,
    by_region,
    glove_contacts,
    long_rows,
    real_contacts,
    twintac_thresholds,
)


def _matrix(table: pa.Table, column: str) -> np.ndarray:
    col = table[column].combine_chunks()
    return col.flatten().to_numpy(zero_copy_only=False).reshape(len(col), -1)


def rig_of(recording: dict) -> Rig:
    """The rig a recording was ingested with (its ``recordings`` row), the default one for rows of a lake
    ingested before rigs were recorded."""
    definition = recording.get("rig_definition")
    return Rig.model_validate_json(definition) if definition else DEFAULT_RIG


def _read(lake: Path, table: str, recording_id: str) -> pa.Table:
    path = lake_io.file_path(lake, table, recording_id)
    if not path.exists():
        raise FileNotFoundError(f"table {table!r} has no rows for recording {recording_id} ({path})")
    return pq.read_table(path)


def human_contacts(lake: Path, recording: dict, config: ContactsConfig) -> tuple[pa.Table, pa.Table]:
    """Contacts (source "human", the 8 robot-paired regions; T5 is dropped) and the two
    glove thresholds of one ingested glove session."""
    rid = recording["recording_id"]
    glove = rig_of(recording).glove
    taxels = _read(lake, "taxels", rid)
    t = taxels["t"].to_numpy()
    contact, resp, thr = glove_contacts(t, _matrix(taxels, "values"), config, glove)
    keep = [HUMAN_REGIONS.index(r) for r in ROBOT_REGIONS]
    rows = long_rows(
        source=Source.HUMAN,
        method=Source.HUMAN,  # the human is the method of its own contacts
        task=recording["task"],
        subject=recording["subject"],
        sequence_id=rid,
        reference_id=rid,
        t=t,
        t_ref=t,
        regions=ROBOT_REGIONS,
        contact=contact[:, keep],
        value=resp[:, keep],
    )
    baseline = float(np.median(thr.baseline[np.asarray(glove.region_of_taxel()) != "-"]))
    method = (
        "k*robust-noise of the smoothed regional response "
        f"(k={config.glove_noise_k}, window={config.smoothing_samples})"
    )
    thresholds = pa.table(
        {
            "recording_id": [rid, rid],
            "sensor": ["glove", "glove"],
            "applies_to": ["fingertip", "palm"],
            "threshold": [thr.fingertip, thr.palm],
            "baseline": [baseline, baseline],
            "noise": [thr.fingertip / config.glove_noise_k, thr.palm / config.glove_noise_k],
            "method": [method, method],
        }
    )
    return rows, thresholds


def replay_contacts(
    lake: Path, replay: dict, calibration_id: str, reference: dict | None, config: ContactsConfig
) -> tuple[pa.Table, pa.Table]:
    """Real-robot contacts of one replay (source "real"), on both its own clock ``t`` and
    the reference trajectory's clock ``t_ref`` (the recorded time map, interpolated), and
    the TwinTac/FSR thresholds used."""
    rid = replay["recording_id"]
    robot = rig_of(replay).robot
    threshold, mean, std = twintac_thresholds(_matrix(_read(lake, "twintac", calibration_id), "values"), config)
    twintac = _read(lake, "twintac", rid)
    fsr = _read(lake, "fsr", rid)
    tmap = _read(lake, "time_map", rid)
    map_t, map_ref = tmap["t"].to_numpy(), tmap["t_ref"].to_numpy()
    tt_raw, fsr_raw = _matrix(twintac, "values"), _matrix(fsr, "values")
    tips, palm = real_contacts(tt_raw, threshold, fsr_raw, config, robot)
    t_tt, t_fsr = twintac["t"].to_numpy(), fsr["t"].to_numpy()
    tip_value = by_region(tt_raw - mean, robot.twintac.regions, ROBOT_REGIONS[:4], np.max)
    palm_value = by_region(fsr_raw, robot.fsr.regions, ROBOT_REGIONS[4:], np.max)
    common = dict(
        source=Source.REAL,
        method=replay["method"],
        task=replay["task"],
        subject=replay["subject"],
        sequence_id=rid,
        reference_id=reference["recording_id"] if reference else "",
    )
    rows = pa.concat_tables(
        [
            long_rows(
                **common,
                t=t_tt,
                t_ref=np.interp(t_tt, map_t, map_ref),
                regions=ROBOT_REGIONS[:4],
                contact=tips,
                value=tip_value,
            ),
            long_rows(
                **common,
                t=t_fsr,
                t_ref=np.interp(t_fsr, map_t, map_ref),
                regions=ROBOT_REGIONS[4:],
                contact=palm,
                value=palm_value,
            ),
        ]
    )
    n, m = len(threshold), fsr_raw.shape[1]
    thresholds = pa.table(
        {
            "recording_id": [rid] * (n + m),
            "sensor": ["twintac"] * n + ["fsr"] * m,
            "applies_to": [f"channel_{i}" for i in range(n)] + [f"channel_{i}" for i in range(m)],
            "threshold": np.r_[threshold, np.full(m, config.fsr_threshold)],
            "baseline": np.r_[mean, np.zeros(m)],
            "noise": np.r_[std, np.zeros(m)],
            "method": [f"calibration {calibration_id}: mean + {config.twintac_noise_k} std"] * n
            + [f"{robot.fsr.units}, > threshold"] * m,
        }
    )
    return rows, thresholds
