"""Flow `teachers`: per task x method PPO teachers that track the human demonstrations and their
contacts, their deterministic rollouts, and the kinematic (Dex Retargeting) replays ->
``rollouts`` and sim ``contacts`` tables, one MLflow run per task x method (stage "teachers")."""

from __future__ import annotations

from prefect import flow

from tasks.common import stored
from tasks.ingest import refresh_catalog
from tasks.runners import ProfileTaskRunner
from tasks.teachers import kinematic_rollouts, report_teachers, teacher_rollouts, train_teacher
from touch2robot import datasets
from touch2robot.config import load_profile
from touch2robot.settings import DataLayout


@flow(name="teachers", task_runner=ProfileTaskRunner(section="training_runner"), log_prints=True)
def teachers(
    profile: str = "smoke",
    data: str | None = None,
    tasks: list[str] | None = None,
    methods: list[str] | None = None,
    seeds: list[int] | None = None,
) -> list[dict]:
    """Train the profile's teachers (``tasks`` x ``methods``, default the profile's ``teacher``
    section) on every retargeted glove demonstration of each task, once per sweep seed (``seeds``,
    default the profile's), record their rollouts and the kinematic baseline's, refresh the catalog
    and report success and contact F1."""
    layout = DataLayout.from_env(data)
    settings = load_profile(profile)
    sweep = settings.sweep(seeds)
    config = settings.teacher
    config = config.model_copy(
        update={"tasks": tuple(tasks or config.tasks), "methods": tuple(methods or config.methods)}
    )
    for m in config.methods:
        config.method(m)  # an unknown method fails here, before any training
    demos: dict[str, list[dict]] = {}
    for r in datasets.retargeted_demonstrations(layout.lake, config.tasks):
        demos.setdefault(r["task"], []).append(r)
    missing = [t for t in config.tasks if t not in demos]
    if missing:
        print(f"teachers: no retargeted demonstrations for {missing}: run the ingest and retarget flows first")
    root = str(layout.root)
    trained, replays = [], []
    for seed in sweep:
        seeded = config.model_copy(update={"seed": settings.for_seed(seed).teacher.seed})
        for task_name, recs in demos.items():
            digest = datasets.references_digest(layout.lake, recs)
            replays.append(
                stored(kinematic_rollouts, layout.results).submit(task_name, seed, seeded, recs, digest, root, profile)
            )
            for method in config.methods:
                run = stored(train_teacher, layout.results).submit(
                    task_name, method, seed, seeded, recs, digest, root, profile
                )
                trained.append(stored(teacher_rollouts, layout.results).submit(run, seeded, recs, digest, root))
    results = [f.result() for f in replays + trained]
    refresh_catalog(root)
    table = report_teachers(profile, results)
    for r in table:
        print(
            f"teachers: {r['task']:7s} {r['method']:16s} seed {r['seed']} success {r['success_rate']:.2f}  "
            f"contact F1 {r['contact_f1']:.3f}"
        )
    return table
