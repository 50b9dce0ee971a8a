"""The reference check (touch2robot.teachers.check, `touch2robot sim check`): the kinematic replay of
every demonstration in MuJoCo, on the one-demonstration-per-task lake of conftest."""

from __future__ import annotations

import dataclasses
import math
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from app.cli import app
from touch2robot import scenes
from touch2robot.leap import mjcf
from touch2robot.settings import DataLayout
from touch2robot.sim.config import SimConfig
from touch2robot.teachers.check import REFERENCE_TARGET, ReferenceCheck, check_references, summarize
from touch2robot.teachers.config import TeacherConfig

runner = CliRunner(env={"COLUMNS": "400"})
SIM = SimConfig(threads=1)


@pytest.fixture(scope="module")
def rows(demo_lake: Path) -> list[ReferenceCheck]:
    return check_references(DataLayout(demo_lake).lake, scenes.TASKS, SIM)


def _said(result) -> str:
    return " ".join(result.output.split())


def _summary_row(output: str, task: str) -> list[str]:
    """The cells of a task's line in the closing table (the last table printed)."""
    lines = [line for line in output.splitlines() if line.startswith(f"│ {task} ")]
    return [cell.strip() for cell in lines[-1].strip("│").split("│")]


def test_every_demonstration_is_replayed_to_its_end(rows: list[ReferenceCheck]) -> None:
    assert sorted(r.task for r in rows) == sorted(scenes.TASKS)  # one demonstration per task
    for r in rows:
        assert r.recording_id and r.subject
        assert r.steps > 20 and r.duration_s == pytest.approx(r.steps * SIM.control_dt)
        assert 0.0 <= r.progress <= 1.0
        assert math.isfinite(r.max_pos_error_m) and math.isfinite(r.max_rot_error_rad)
        assert r.lost_at_s is None or 0.0 < r.lost_at_s <= r.duration_s
    assert {s.task: s.demonstrations for s in summarize(rows, scenes.TASKS)} == dict.fromkeys(scenes.TASKS, 1)


def test_the_rotate_reference_succeeds(rows: list[ReferenceCheck]) -> None:
    (rotate,) = [r for r in rows if r.task == "rotate"]
    assert rotate.success and rotate.lost_at_s is None
    assert rotate.max_pos_error_m < TeacherConfig().lost_pos_m
    (summary,) = summarize(rows, ["rotate"])
    assert summary.rate == 1.0 and summary.passed


def test_the_wipe_reference_drags_the_sponge_only_with_its_compliance_and_noslip(
    rows: list[ReferenceCheck], demo_lake: Path
) -> None:
    """The pressing palm drags the compliant sponge through the path. The same demonstration on a rigid
    sponge at the max rule's friction, without noslip passes, lets the sponge creep under the palm:
    it lags its reference farther (measured at the local profile: 4 of 8 replays passed)."""
    (wipe,) = [r for r in rows if r.task == "wipe"]
    assert wipe.success and wipe.progress == 1.0 and wipe.lost_at_s is None
    spec = scenes.get("wipe")
    rigid_sponge = dataclasses.replace(spec.object, solref=None, solimp=None, table_friction=None)
    rigid = dataclasses.replace(spec, object=rigid_sponge, noslip_iterations=0)
    (crept,) = check_references(DataLayout(demo_lake).lake, ["wipe"], SIM, spec_override={"wipe": rigid})
    assert crept.max_pos_error_m > wipe.max_pos_error_m + 0.005, (crept, wipe)


def test_a_scene_without_friction_fails_the_check(
    demo_lake: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With no friction on the object, the hand's links and its pads, no grasp holds the cube: the
    same reference that succeeds above loses the object. (The object's friction alone is not
    enough: a contact takes the larger friction of its two geoms, so the pads' would still hold.)"""
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the squeezed-out cube's instability to ./MUJOCO_LOG.TXT
    monkeypatch.setattr(mjcf, "HAND_FRICTION", 0.0)
    monkeypatch.setattr(mjcf, "PAD_FRICTION", 0.0)
    spec = scenes.get("rotate")
    frictionless = dataclasses.replace(spec, object=dataclasses.replace(spec.object, friction=0.0))
    (rotate,) = check_references(DataLayout(demo_lake).lake, ["rotate"], SIM, spec_override={"rotate": frictionless})
    assert not rotate.success and (rotate.lost_at_s is not None or rotate.physics_error is not None)
    (summary,) = summarize([rotate], ["rotate"])
    assert summary.rate == 0.0 and not summary.passed


def test_the_cli_exit_code_follows_the_target(rows: list[ReferenceCheck], demo_lake: Path, tmp_path: Path) -> None:
    root = tmp_path / "data"
    shutil.copytree(demo_lake, root)
    rotate = runner.invoke(app, ["sim", "check", "--data", str(root), "--task", "rotate", "--each"])
    assert rotate.exit_code == 0, rotate.output
    (demo,) = [r for r in rows if r.task == "rotate"]
    assert demo.recording_id in rotate.output  # --each: the demonstration's line
    assert _summary_row(rotate.output, "rotate") == ["rotate", "1", "1", "1.00", "pass"]

    every = runner.invoke(app, ["sim", "check", "--data", str(root)])
    summaries = summarize(rows, scenes.TASKS)
    assert every.exit_code == (0 if all(s.passed for s in summaries) else 1), every.output
    for s in summaries:
        result = "pass" if s.passed else "FAIL"
        assert _summary_row(every.output, s.task) == [s.task, "1", str(s.successes), f"{s.rate:.2f}", result]
    assert f"target {REFERENCE_TARGET:.2f}" in every.output


def test_nothing_to_replay_is_named(demo_lake: Path, tmp_path: Path) -> None:
    empty = runner.invoke(app, ["sim", "check", "--data", str(tmp_path / "empty")])
    assert empty.exit_code == 2
    assert f"no lake in {tmp_path / 'empty'}" in _said(empty) and "touch2robot retarget" in _said(empty)
    assert not (tmp_path / "empty").exists()  # the check only reads

    root = tmp_path / "data"
    shutil.copytree(demo_lake, root)
    layout = DataLayout(root)
    shutil.rmtree(layout.lake / "retargeted")
    assert summarize(check_references(layout.lake, ["rotate"], SIM), ["rotate"])[0].rate is None
    unretargeted = runner.invoke(app, ["sim", "check", "--data", str(root), "--task", "rotate"])
    assert unretargeted.exit_code == 2
    assert "no retargeted demonstrations of rotate" in _said(unretargeted)
    assert f"touch2robot retarget --data {root}" in _said(unretargeted)
