"""Flow `policy`: per task x method with rollouts in the lake (the most preferred origin of the
profile's ``policy.origins``, default student > teacher > kinematic), the LeRobot dataset of its
robot demonstrations, LeRobot's Diffusion Policy trained on it and its closed-loop success
(``policy_eval`` table, MLflow runs of stage "policy")."""

from __future__ import annotations

from prefect import flow, unmapped

from tasks.common import stored
from tasks.ingest import refresh_catalog
from tasks.policy import build_policy_dataset, evaluate_policy, report_policy, rollout_sources, train_policy
from tasks.runners import ProfileTaskRunner
from touch2robot.config import load_profile
from touch2robot.datasets import ROLLOUTS
from touch2robot.settings import DataLayout


@flow(name="policy", task_runner=ProfileTaskRunner(section="training_runner"), log_prints=True)
def policy(
    profile: str = "smoke",
    data: str | None = None,
    tasks: list[str] | None = None,
    methods: list[str] | None = None,
    seeds: list[int] | None = None,
) -> list[dict]:
    """Datasets -> training -> closed-loop evaluation for every task x method in ``rollouts``
    (narrowed by ``tasks`` / ``methods``, default the profile's ``policy`` section), once per sweep
    seed (``seeds``, default the profile's) on that seed's rollouts."""
    layout = DataLayout.from_env(data)
    settings = load_profile(profile)
    root = str(layout.root)
    # replays and evaluation run the physics the rollouts were recorded with (the teachers' sim)
    sim = settings.teacher.sim
    evaluated = []
    for seed in settings.sweep(seeds):
        config = settings.for_seed(seed).policy
        sources = rollout_sources(root, config, tasks or config.tasks, methods or config.methods, seed)
        if not sources:
            print(f"policy: no rollouts of seed {seed} in {ROLLOUTS.folder(layout.lake)} (run the teachers first)")
            continue
        datasets = stored(build_policy_dataset, layout.results).map(
            sources, unmapped(config), unmapped(sim), unmapped(root)
        )
        trained = stored(train_policy, layout.results).map(
            datasets, unmapped(config), unmapped(root), unmapped(profile)
        )
        evaluated += stored(evaluate_policy, layout.results).map(
            trained, unmapped(config), unmapped(sim), unmapped(root), unmapped(profile)
        )
    if not evaluated:
        return []
    rows = [f.result() for f in evaluated]
    refresh_catalog(root)
    report_policy(profile, rows)
    for r in rows:
        print(
            f"policy {r['task']:>7} x {r['method']:<16} seed {r['seed']} ({r['origin']}, sees {r['observation']}): "
            "success "
            f"{r['successes']}/{r['episodes']} = {r['success_rate']:.2f} [{r['ci_low']:.2f}, {r['ci_high']:.2f}], "
            f"progress {r['mean_progress']:.2f}, "
            f"demonstrations replayed {r['replay_successes']}/{r['episodes']}, "
            f"open-loop error {r['fit_joint_err_rad']:.3f} rad / {r['fit_wrist_err_mm']:.1f} mm (holding still: "
            f"{r['hold_joint_err_rad']:.3f} / {r['hold_wrist_err_mm']:.1f})"
        )
    return rows
