"""Hardware-twin throughput: replays/s and env (physics) steps/s of ``replay_rollouts`` as the replay stage runs
it, one batch per round (perturbed rig, sensor models, both MCAPs written) on scripted grasp rollouts of a few
tasks, next to the raw MuJoCo ceiling measured in the same run: each replay's own perturbed model stepped by
``mujoco.rollout`` in one call over the same steps and control sequence, outputs preallocated, no sensors, no
writing. Rounds interleave the two so that load from other processes hits both alike; the best round of each
is reported.

    uv run python bench/twin.py [--tasks pick drawer] [--rollouts 3] [--steps 60] [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
from mujoco import rollout

from touch2robot.sim.config import SimConfig
from touch2robot.sim.env import CONTROL_SPEC
from touch2robot.twin.config import TwinConfig
from touch2robot.twin.replay import ReplayOutcome, ReplayRequest, replay_rollouts, twin_physics

ROOT = Path(__file__).resolve().parents[1]


def scripted(tasks: list[str], n: int, steps: int) -> list[pa.Table]:
    """One table per rollout: the tests' scripted grasps (real physics) of each task."""
    sys.path.insert(0, str(ROOT / "tests"))
    from conftest import scripted_rollout_rows

    out = []
    for task in tasks:
        rows = scripted_rollout_rows(task, "touch2robot", n, steps)
        ids = np.asarray(rows["rollout_id"].to_pylist())
        out.extend(rows.filter(pa.array(ids == rid)) for rid in sorted(set(ids)))
    return out


def run_twin(
    rollouts: list[pa.Table], sim: SimConfig, twin: TwinConfig, folder: Path
) -> tuple[float, int, list[ReplayOutcome]]:
    """Seconds for all replays (files written), physics steps, and the outcomes."""
    requests = []
    for i, rows in enumerate(rollouts):
        metadata = {
            "task": rows["task"][0].as_py(),
            "subject": "s00",
            "method": "touch2robot",
            "reference_recording": f"ref{i}.mcap",
            "calibration_recording": f"calib{i}.mcap",
            "rig": "hardware-twin",
        }
        requests.append(ReplayRequest(rows, [0, i], folder / f"replay{i}.mcap", folder / f"calib{i}.mcap", metadata))
    start = time.perf_counter()
    outcomes = list(replay_rollouts(requests, sim, twin))
    elapsed = time.perf_counter() - start
    replayed = [o for o in outcomes if isinstance(o, ReplayOutcome)]
    if len(replayed) < len(outcomes):
        raise SystemExit(f"a scripted rollout failed on the twin: {next(o for o in outcomes if o not in replayed)}")
    return elapsed, sum(o.steps for o in replayed), replayed


def run_ceiling(rollouts: list[pa.Table], sim: SimConfig, twin: TwinConfig) -> float:
    """Seconds of raw rollout over every replay's model, steps and controls (prepared outside the clock)."""
    prepared = [twin_physics(rows, sim, twin, [0, i]) for i, rows in enumerate(rollouts)]
    outputs = [
        (np.empty((1, len(p.control), len(p.initial_state))), np.empty((1, len(p.control), p.rig.model.nsensordata)))
        for p in prepared
    ]
    elapsed = 0.0
    with rollout.Rollout(nthread=0) as pool:
        for p, (state, sensordata) in zip(prepared, outputs, strict=True):
            start = time.perf_counter()
            pool.rollout(
                p.rig.model,
                p.data,
                p.initial_state[None],
                p.control[None],
                control_spec=CONTROL_SPEC,
                nstep=len(p.control),
                state=state,
                sensordata=sensordata,
            )
            elapsed += time.perf_counter() - start
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["pick", "drawer"])
    parser.add_argument("--rollouts", type=int, default=3, help="scripted rollouts per task")
    parser.add_argument("--steps", type=int, default=60, help="control steps per rollout")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    sim, twin = SimConfig(threads=1), TwinConfig()
    rollouts = scripted(args.tasks, args.rollouts, args.steps)
    twin_s, ceiling_s = [], []
    with tempfile.TemporaryDirectory() as folder:
        _, steps, outcomes = run_twin(rollouts, sim, twin, Path(folder))  # warm-up: scene cache, imports
        for _ in range(args.rounds):
            twin_s.append(run_twin(rollouts, sim, twin, Path(folder))[0])
            ceiling_s.append(run_ceiling(rollouts, sim, twin))
        size = sum(o.replay_path.stat().st_size + o.calibration_path.stat().st_size for o in outcomes)
    best_twin, best_ceiling = min(twin_s), min(ceiling_s)
    n = len(rollouts)
    contact = np.mean([np.mean(o.contact_fraction[:4]) for o in outcomes])
    print(
        f"{n} scripted rollouts ({', '.join(args.tasks)}; {args.steps} control steps + {twin.hold_s:g} s hold each), "
        f"{steps} physics steps of {sim.timestep} s in all, {os.cpu_count()} CPUs, best of {args.rounds} "
        "interleaved rounds"
    )
    print(f"mean share of 100 Hz samples with a fingertip region in contact: {contact:.0%}")
    print(f"files written per round: {2 * n} ({size / 1e6:.2f} MB)")
    print(f"{'':30s}{'replays/s':>12s}{'env steps/s':>14s}")
    print(f"{'twin (replay_rollouts)':30s}{n / best_twin:12.1f}{steps / best_twin:14.0f}")
    print(f"{'ceiling (mujoco.rollout)':30s}{n / best_ceiling:12.1f}{steps / best_ceiling:14.0f}")
    print(f"ratio twin / ceiling: {best_ceiling / best_twin:.2f}   (target >= 0.80)")


if __name__ == "__main__":
    main()
