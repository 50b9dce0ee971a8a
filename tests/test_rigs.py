"""Rig files: a lab's glove and robot described by a YAML file, not by code. A second glove (128 taxels in
another layout, other topic names and joint names) ingests from its rig file alone and its contacts match
the demonstrator's ground truth; a bad rig is refused, naming the file and field, before any file is
ingested."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from typer.testing import CliRunner

from app.cli import app
from schemas.rig import DEFAULT_RIG
from schemas.tables import ROBOT_REGIONS
from touch2robot.config import load_profile
from touch2robot.contacts import ContactsConfig, real_contacts
from touch2robot.contacts.extract import human_contacts
from touch2robot.ingest import ingest_file, recording_rows
from touch2robot.ingest.rigs import RigError, checked_rigs, find_rigs, load_rig, parse_rig, write_rig
from touch2robot.metrics import contact_scores
from touch2robot.synth.generate import plan, write_recording

LAB_TAXELS = 128
LAB_TIP, LAB_PALM = 12, 14  # taxels per fingertip and per palm pad; 12 taxels of no region


def lab_rig_data() -> dict:
    """A second glove: 128 taxels whose regions are scattered over the array, 80 Hz, other topics, its
    SDK's own joint names; a robot with 2 TwinTac channels per fingertip."""
    order = [int(i) for i in np.random.default_rng(7).permutation(LAB_TAXELS)]
    fingertip = {f"T{k + 1}": {"taxels": order[k * LAB_TIP : (k + 1) * LAB_TIP]} for k in range(5)}
    start = 5 * LAB_TIP
    palm: dict[str, dict[str, object]] = {
        f"P{k + 1}": {"taxels": order[start + k * LAB_PALM : start + (k + 1) * LAB_PALM]} for k in range(4)
    }
    palm["P4"]["threshold_k"] = 6.0  # a per-region threshold option
    streams = {
        "taxels": ("/lab2/glove/pressure", 80.0),
        "hand_joints": ("/lab2/glove/angles", 50.0),
        "hand_keypoints": ("/lab2/mocap/hand", 50.0),
        "wrist_pose": ("/lab2/mocap/wrist", 50.0),
        "object_pose": ("/lab2/mocap/object", 50.0),
        "robot_joint_states": ("/lab2/leap/state", 50.0),
        "robot_joint_targets": ("/lab2/leap/command", 20.0),
        "twintac": ("/lab2/tips", 100.0),
        "fsr": ("/lab2/palm", 50.0),
        "time_map": ("/lab2/replay_clock", 20.0),
    }
    return {
        "name": "lab2",
        "description": "a 128-taxel glove",
        "streams": {k: {"topic": t, "rate_hz": r} for k, (t, r) in streams.items()},
        "glove": {
            "n_taxels": LAB_TAXELS,
            "fingertip": fingertip,
            "palm": palm,
            "joint_names": [f"sdk_angle_{i:02d}" for i in range(20)],
        },
        "robot": {
            "joint_names": [str(i) for i in range(16)],
            "twintac": {"units": "counts", "regions": [r for r in ("T1", "T2", "T3", "T4") for _ in range(2)]},
            "fsr": {"units": "mV", "regions": ["P1", "P2", "P3", "P4"]},
        },
    }


@pytest.fixture(scope="module")
def lab_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The smoke profile's demonstrations recorded on the lab's rig: its rig file beside them."""
    root = tmp_path_factory.mktemp("lab") / "data"
    recordings = root / "recordings"
    recordings.mkdir(parents=True)
    (recordings / "lab2.rig.yaml").write_text(yaml.safe_dump(lab_rig_data(), sort_keys=False))
    rig = load_rig(recordings / "lab2.rig.yaml")
    config = load_profile("smoke").synth
    for job in plan(config):
        write_recording(config, job, recordings, root / "groundtruth", rig=rig)
    return root


def test_the_default_rig_file_reads_back_as_the_built_in_rig(tmp_path: Path) -> None:
    path = write_rig(DEFAULT_RIG, tmp_path)
    assert path.name == "simulated.rig.yaml"
    assert "0-23" in path.read_text()  # taxel runs written as ranges
    assert load_rig(path) == DEFAULT_RIG
    assert find_rigs(tmp_path).by_name == {"simulated": DEFAULT_RIG}


def test_a_128_taxel_glove_on_other_topics_ingests_from_its_rig_file_and_its_contacts_match_ground_truth(
    lab_data: Path, tmp_path: Path
) -> None:
    recordings = lab_data / "recordings"
    rigs = checked_rigs(recordings, [], {})
    lake = tmp_path / "lake"
    paths = sorted(recordings.glob("*.mcap"))
    for path in paths:
        result = ingest_file(path, lake, rigs=rigs.by_name)
        assert result.status == "ingested", result.reason
    rows = recording_rows(lake).to_pylist()
    assert {r["rig"] for r in rows} == {"lab2"}
    refs, evals = [], []
    for rec in rows:
        taxels = pq.read_table(lake / "taxels" / f"{rec['recording_id']}.parquet")
        assert len(taxels["values"][0]) == LAB_TAXELS
        assert taxels.num_rows == pytest.approx(taxels["t"].to_numpy()[-1] * 80, rel=0.05)  # the rig's 80 Hz
        contacts, _ = human_contacts(lake, rec, ContactsConfig())
        wide = contacts.to_pandas().pivot(index="t", columns="region", values="contact")[list(ROBOT_REGIONS)]
        gt = pq.read_table(lab_data / "groundtruth" / f"{Path(rec['path']).stem}.parquet").to_pandas()
        truth = gt.pivot(index="t", columns="region", values="contact")[list(ROBOT_REGIONS)]
        np.testing.assert_allclose(wide.index.to_numpy(), truth.index.to_numpy(), atol=1e-6)
        refs.append(truth.to_numpy())
        evals.append(wide.to_numpy())
    pooled = contact_scores(np.concatenate(refs), np.concatenate(evals))
    assert pooled.f1 >= 0.95, pooled


def test_a_recording_naming_a_rig_ingest_does_not_know_is_quarantined_saying_where_to_give_it(
    lab_data: Path, tmp_path: Path
) -> None:
    path = sorted((lab_data / "recordings").glob("*.mcap"))[0]
    result = ingest_file(path, tmp_path / "lake")  # only the built-in rig
    assert result.status == "quarantined"
    assert "'lab2'" in result.reason and "lab2.rig.yaml" in result.reason and "--rig" in result.reason


def _with(data: dict, where: str, value: object) -> dict:
    node = data
    *parents, last = where.split(".")
    for key in parents:
        node = node[key]
    node[last] = value
    return data


@pytest.mark.parametrize(
    ("where", "value", "said"),
    [
        ("glove.fingertip.T2.taxels", [3, 4, 300], "glove.fingertip.T2.taxels: taxel 300 is out of range"),
        ("glove.palm.P3.taxels", [], "glove.palm.P3.taxels: the region is empty"),
        ("streams.taxels.topic", "/lab2/glove/tactile", "streams.taxels.topic: /lab2/glove/tactile is in none"),
    ],
)
def test_a_bad_rig_is_refused_naming_the_field_before_any_file_is_ingested(
    lab_data: Path, tmp_path: Path, where: str, value: object, said: str
) -> None:
    root = tmp_path / "data"
    shutil.copytree(lab_data, root)
    rig_file = root / "recordings" / "lab2.rig.yaml"
    rig_file.write_text(yaml.safe_dump(_with(lab_rig_data(), where, value), sort_keys=False))
    with pytest.raises(RigError) as refused:
        checked_rigs(root / "recordings", [], {})
    assert str(rig_file) in str(refused.value) and said in str(refused.value)

    result = CliRunner(env={"COLUMNS": "400"}).invoke(app, ["ingest", "--data", str(root)])
    assert result.exit_code == 2, result.output
    assert said in " ".join(result.output.split())
    assert not (root / "lake" / "recordings").exists()  # not one file ingested


@pytest.mark.parametrize(
    ("where", "value", "said"),
    [
        ("name", "../lab", "name: String should match pattern"),
        ("glove.n_taxels", True, "glove.n_taxels: expected a number"),
        ("glove.fingertip.T6", {"taxels": [0]}, "glove.fingertip: the regions are T1, T2, T3, T4, T5; unknown T6"),
        ("glove.palm.P1.taxels", ["9-3"], "range '9-3' runs backwards"),
        ("glove.palm.P2.taxels", "T1's first", "glove.palm.P2.taxels: taxel {first} is also in fingertip.T1"),
        ("robot.joint_names", ["a"] * 16, "robot.joint_names: 16 distinct names"),
        ("robot.fsr.regions", ["P1", "P2", "P3"], "robot.fsr.regions: no channel senses P4"),
        ("streams.fsr.topic", "/lab2/tips", "topic /lab2/tips carries two streams of a robot_replay"),
        ("streams.taxels.topic", "glove taxels", "streams.taxels.topic: String should match pattern"),
    ],
)
def test_rig_file_errors_name_the_field(where: str, value: object, said: str) -> None:
    data = lab_rig_data()
    first = data["glove"]["fingertip"]["T1"]["taxels"][0]
    if value == "T1's first":
        value = [first]
    with pytest.raises(RigError) as refused:
        parse_rig(yaml.safe_dump(_with(data, where, value)), "lab2.rig.yaml")
    assert "lab2.rig.yaml" in str(refused.value) and said.format(first=first) in str(refused.value)


def test_a_rig_file_with_a_key_given_twice_is_refused() -> None:
    text = yaml.safe_dump(lab_rig_data(), sort_keys=False) + "name: lab3\n"
    with pytest.raises(RigError, match="duplicate key 'name'"):
        parse_rig(text, "lab2.rig.yaml")


def test_two_rig_files_defining_one_name_differently_are_refused(tmp_path: Path) -> None:
    (tmp_path / "a.rig.yaml").write_text(yaml.safe_dump(lab_rig_data()))
    other = _with(lab_rig_data(), "description", "another glove")
    (tmp_path / "b.rig.yaml").write_text(yaml.safe_dump(other))
    with pytest.raises(RigError, match="name 'lab2' is also defined, differently, by"):
        find_rigs(tmp_path)


def test_real_contacts_follow_the_rigs_channels() -> None:
    robot = parse_rig(yaml.safe_dump(lab_rig_data()), "lab2.rig.yaml").robot
    # 8 TwinTac channels, 2 per fingertip: channel 5 (T3) over its threshold; FSR P2 loaded
    twintac = np.zeros((3, 8))
    twintac[1, 5] = 10.0
    fsr = np.zeros((3, 4))
    fsr[2, 1] = 1.0
    tips, palm = real_contacts(twintac, np.ones(8), fsr, ContactsConfig(), robot)
    assert tips.tolist() == [[False] * 4, [False, False, True, False], [False] * 4]
    assert palm.tolist() == [[False] * 4, [False] * 4, [False, True, False, False]]


def test_a_recording_lacking_a_topic_of_the_built_in_rig_is_quarantined_not_the_whole_ingest(
    smoke_data: Path, tmp_path: Path
) -> None:
    """The built-in rig is the contract: the one recording lacking its topic is at fault, and only it."""
    from touch2robot.recording import cdr
    from touch2robot.recording.writer import RecordingWriter

    folder = tmp_path / "recordings"
    folder.mkdir()
    shutil.copy(sorted((smoke_data / "recordings").glob("*.mcap"))[0], folder)
    lacking = folder / "pick_s09_d01_glove.mcap"
    with RecordingWriter(lacking, "glove_session", {"task": "pick", "subject": "s09"}) as w:
        w.write("/glove/taxels", 10**9, cdr.encode_tactile(10**9, "glove_right", np.zeros(256)))
    rigs = checked_rigs(folder, [], {})  # no RigError
    results = {p.name: ingest_file(p, tmp_path / "lake", rigs=rigs.by_name) for p in sorted(folder.glob("*.mcap"))}
    assert results.pop(lacking.name).status == "quarantined"
    assert [r.status for r in results.values()] == ["ingested"]
