"""Contacts recovered from the recordings: the glove's against the demonstrator's ground truth, the robot's
(TwinTac, FSR) against the forces the hardware twin measured."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from schemas.glove import TAXEL_REGION
from schemas.tables import HUMAN_REGIONS, ROBOT_REGIONS
from touch2robot.contacts import ContactsConfig, glove_contacts, regional_responses
from touch2robot.contacts.extract import _matrix, human_contacts, replay_contacts
from touch2robot.ingest import ingest_file, link_replays, recording_rows
from touch2robot.metrics import contact_scores


@pytest.fixture(scope="module")
def ingested(replay_data: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict]]:
    lake = tmp_path_factory.mktemp("contacts") / "lake"
    for p in sorted((replay_data / "recordings").glob("*.mcap")):
        assert ingest_file(p, lake).status == "ingested"
    return lake, recording_rows(lake).to_pylist()


def _truth(smoke_data: Path, recording: dict, regions: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    gt = pq.read_table(smoke_data / "groundtruth" / f"{Path(recording['path']).stem}.parquet").to_pandas()
    wide = gt.pivot(index="t", columns="region", values="contact")[list(regions)]
    return wide.index.to_numpy(), wide.to_numpy()


def test_human_contacts_match_ground_truth(smoke_data: Path, ingested) -> None:
    lake, rows = ingested
    refs, evals = [], []
    for rec in (r for r in rows if r["kind"] == "glove_session"):
        table, thresholds = human_contacts(lake, rec, ContactsConfig())
        df = table.to_pandas()
        assert set(df.region) == set(ROBOT_REGIONS)  # T5 excluded
        wide = df.pivot(index="t", columns="region", values="contact")[list(ROBOT_REGIONS)]
        t, truth = _truth(smoke_data, rec, ROBOT_REGIONS)
        np.testing.assert_allclose(wide.index.to_numpy(), t, atol=1e-6)
        scores = contact_scores(truth, wide.to_numpy())
        assert scores.f1 >= 0.93, (rec["file_name"], scores)
        assert set(thresholds["applies_to"].to_pylist()) == {"fingertip", "palm"}
        refs.append(truth)
        evals.append(wide.to_numpy())
    pooled = contact_scores(np.concatenate(refs), np.concatenate(evals))
    assert pooled.f1 >= 0.95, pooled


def test_thresholds_must_be_recording_specific(smoke_data: Path, ingested) -> None:
    """Recordings differ in baseline offsets and gains: even the best single threshold on
    the raw regional counts, chosen with hindsight over all recordings, does clearly worse
    than the per-recording thresholds."""
    lake, rows = ingested
    config = ContactsConfig()
    raw_sums, truths, own = [], [], []
    for rec in (r for r in rows if r["kind"] == "glove_session"):
        taxels = pq.read_table(lake / "taxels" / f"{rec['recording_id']}.parquet")
        values = _matrix(taxels, "values")
        contact, _, _ = glove_contacts(taxels["t"].to_numpy(), values, config)
        _, truth = _truth(smoke_data, rec, HUMAN_REGIONS)
        region_of = np.asarray(TAXEL_REGION)
        raw_sums.append(np.stack([values[:, region_of == r].sum(axis=1) for r in HUMAN_REGIONS], 1))
        truths.append(truth)
        own.append(contact)
    levels = [float(np.median(s)) for s in raw_sums]
    assert max(levels) / min(levels) > 1.5  # per-recording offsets differ a lot
    truth_all, raw_all = np.concatenate(truths), np.concatenate(raw_sums)
    best_global = max(
        contact_scores(truth_all, raw_all > thr).f1 for thr in np.quantile(raw_all, np.linspace(0.01, 0.99, 99))
    )
    per_recording = contact_scores(truth_all, np.concatenate(own)).f1
    assert per_recording > 0.95 and best_global < per_recording - 0.1, (best_global, per_recording)


def test_regional_response_rejects_wrong_shape() -> None:
    with pytest.raises(ValueError, match=r"\(time, 256\)"):
        regional_responses(np.zeros((10, 255)), ContactsConfig())


def test_real_contacts_from_twintac_and_fsr(replay_data: Path, ingested) -> None:
    """Per-channel TwinTac thresholds from the calibration and FSR > 0 recover the contacts the twin's
    physics made: each replayed rollout's own region forces (> 0.5 N) at its 20 Hz steps, through the
    replay's time map."""
    lake, rows = ingested
    _, links, _ = link_replays(rows)
    assert len(links) == 4
    refs, evals = [], []
    for link in links:
        table, thresholds = replay_contacts(lake, link.replay, link.calibration_id, link.reference, ContactsConfig())
        df = table.to_pandas()
        assert link.reference is not None
        assert (df.reference_id == link.reference["recording_id"]).all()
        rollout = pq.read_table(
            replay_data / "lake" / "rollouts" / "method=touch2robot" / f"teacher-{link.replay['task']}-seed0.parquet"
        ).to_pandas()
        force = np.stack(rollout["region_force"].to_numpy())
        for r, region in enumerate(ROBOT_REGIONS):
            measured = df[df.region == region].sort_values("t")
            # the last measured sample at or before each step's reference time
            at = np.searchsorted(measured.t_ref.to_numpy(), rollout["t_ref"].to_numpy(), side="right") - 1
            keep = at >= 0
            refs.append(force[keep, r] > 0.5)
            evals.append(measured.contact.to_numpy()[at[keep]])
        tt = thresholds.to_pandas().query("sensor == 'twintac'")
        fsr = thresholds.to_pandas().query("sensor == 'fsr'")
        assert (fsr.threshold == 0).all() and len(fsr) == 4 and len(tt) == 16 and (tt.noise > 0).all()
    truth, measured = np.concatenate(refs), np.concatenate(evals)
    assert truth.mean() > 0.05  # the scripted grasps touch
    f1 = contact_scores(truth[:, None], measured[:, None]).f1
    assert f1 > 0.7, f1
