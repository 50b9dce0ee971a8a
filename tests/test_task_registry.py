"""The task suite is discovered from the modules of ``touch2robot.scenes``: its order is fixed (it seeds
the demonstrator and orders every output), and adding a task is adding one module, which then
reaches every stage that names tasks."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from touch2robot import scenes

# A toy task in one module: slide a puck to a goal under the flat palm. Nothing else is edited.
TOY_MODULE = '''
"""Slide: press a puck with the flat palm and push it to a goal."""

import numpy as np

from touch2robot.scenes.base import SuccessCriterion, Task
from touch2robot.scenes.spec import GeomSpec, ObjectSpec, TaskSpec
from touch2robot.synth.demos import Q_FLAT, offset, yaw
from touch2robot.synth.motion import _Builder

SIZE = (0.03, 0.03, 0.01)


def default_config() -> TaskSpec:
    return TaskSpec(
        name="slide",
        object=ObjectSpec(
            "puck", (GeomSpec("cylinder", (SIZE[0], SIZE[2])),), mass=0.05, friction=0.5, init_pos=(-0.05, 0.0, SIZE[2])
        ),
        episode_s=6.0,
        goal_pos=(0.08, 0.0, SIZE[2]),
        success={"pos_tol_m": 0.02},
    )


class SlideSuccess(SuccessCriterion):
    def update(self, pos0, quat0, pos, quat, opening):
        dist = np.linalg.norm(pos[:, :2] - np.asarray(self.spec.goal_pos)[:2], axis=1)
        start = np.linalg.norm(pos0[:, :2] - np.asarray(self.spec.goal_pos)[:2], axis=1)
        progress = np.clip(1.0 - dist / np.maximum(start, 1e-9), 0.0, 1.0)
        return dist <= self.spec.success["pos_tol_m"], progress


def demonstrate(spec, hand, rng, pace):
    obj_pos, obj_quat = np.asarray(spec.object.init_pos), yaw(0.0)
    depth = rng.uniform(0.003, 0.006)
    press = offset(obj_pos, obj_quat, [-0.05 * hand.scale, 0.0, SIZE[2] + 0.015 * hand.scale - depth])
    b = _Builder(press + [0.0, 0.0, 0.10], obj_quat, Q_FLAT, obj_pos, obj_quat)
    b.phase(1.0 * pace, wrist_pos=press)
    b.carry(1.5 * pace, np.asarray(spec.goal_pos), obj_quat)
    b.phase(0.8 * pace, wrist_pos=b.state[1] + [0.0, 0.0, 0.10])
    return b.build()


TASK = Task(
    name="slide",
    position=4,
    instruction="slide the puck to the goal",
    default_config=default_config,
    demonstrate=demonstrate,
    criterion=SlideSuccess,
)
'''

# Run in a fresh interpreter: the toy folder joins the package's __path__ before the package (and so
# its registry) is first imported, and no other test process ever sees the toy task.
PROBE = """
import importlib.util, json, sys
from pathlib import Path

toy_dir, data = sys.argv[1], Path(sys.argv[2])
package_spec = importlib.util.find_spec("touch2robot.scenes")
package_spec.submodule_search_locations.append(toy_dir)
package = importlib.util.module_from_spec(package_spec)
sys.modules["touch2robot.scenes"] = package
package_spec.loader.exec_module(package)

import numpy as np
import pyarrow.parquet as pq

from touch2robot import scenes
from touch2robot.policy import dataset
from touch2robot.sim.scene import build_scene
from touch2robot.sim.success import SuccessTracker
from touch2robot.student import augment
from touch2robot.synth import generate
from touch2robot.synth.config import SynthConfig
from touch2robot.teachers.config import TeacherConfig

config = SynthConfig(tasks=("slide",), subjects=1, demos_per_subject=1)
job = generate.plan(config)[0]
generate.write_recording(config, job, data / "recordings", data / "groundtruth")
_, demo, _ = generate._demonstration(config, job)
tracker = SuccessTracker(scenes.get("slide"), 2)
tracker.reset(np.arange(2), demo.object_pos[[0, 0]], demo.object_quat[[0, 0]])
tracker.update(demo.object_pos[[0, -1]], demo.object_quat[[0, -1]], np.zeros(2))
rollouts = data / "lake" / "rollouts" / "method=touch2robot"
rollouts.mkdir(parents=True)
(rollouts / "kinematic-slide-seed0.parquet").touch()
print(json.dumps({
    "tasks": scenes.TASKS,
    "synth_default": SynthConfig().tasks,
    "teachers_default": TeacherConfig().tasks,
    "student_counts": augment.per_task_counts(5, ["slide", "drawer"]),
    "scene_bodies": build_scene("slide").model.nbody,
    "recorded": sorted(p.name for p in (data / "recordings").iterdir()),
    "groundtruth_rows": pq.read_table(data / "groundtruth" / f"{job.stem}.parquet").num_rows,
    "success": tracker.success.tolist(),
    "progress": tracker.progress.tolist(),
    "instruction": scenes.task("slide").instruction,
    "policy_sources": [s.task for s in dataset.sources(data / "lake")],
}))
"""


def test_suite_order_is_fixed() -> None:
    """The order seeds the demonstrator's random streams and orders every output: never reorder."""
    assert scenes.TASKS == ("pick", "rotate", "wipe", "drawer")
    assert [scenes.task(t).position for t in scenes.TASKS] == [0, 1, 2, 3]
    assert all(scenes.get(t).name == t for t in scenes.TASKS)


@pytest.mark.parametrize(
    "module", ["touch2robot.geometry", "touch2robot.synth.motion", "touch2robot.synth.demos", "touch2robot.scenes.spec"]
)
def test_the_building_blocks_of_task_modules_import_first(module: str) -> None:
    """Importing touch2robot.scenes imports every task module, so what they import must not import the
    package back at run time (it would meet itself half initialised)."""
    probe = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True, timeout=300)
    assert probe.returncode == 0, probe.stderr[-3000:]


def test_a_new_task_module_is_registered_everywhere(tmp_path: Path) -> None:
    toy_dir = tmp_path / "toy_tasks"
    toy_dir.mkdir()
    (toy_dir / "slide.py").write_text(TOY_MODULE)
    probe = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(PROBE), str(toy_dir), str(tmp_path / "data")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert probe.returncode == 0, probe.stderr[-3000:]
    seen = json.loads(probe.stdout.strip().splitlines()[-1])
    assert seen["tasks"] == ["pick", "rotate", "wipe", "drawer", "slide"]
    assert seen["synth_default"] == seen["teachers_default"] == seen["tasks"]
    assert seen["student_counts"] == {"drawer": 3, "slide": 2}  # in suite order: the new task last
    assert seen["scene_bodies"] > 1
    assert seen["recorded"] == ["slide_s01_d01_glove.mcap"]
    assert seen["groundtruth_rows"] > 0
    assert seen["success"] == [False, True]  # at the start, and where the scripted demonstration leaves the puck
    assert seen["progress"][1] > 0.5
    assert seen["instruction"] == "slide the puck to the goal"
    assert seen["policy_sources"] == ["slide"]
    assert "slide" not in scenes.REGISTRY  # this process never saw the toy task
