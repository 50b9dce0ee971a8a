"""Flow `student`: the unified student retargeter. Augment the teachers' rollouts (lake
``student_dataset``), distil the full model and each ablation of the profile's ``student``
section (one MLflow run each, stage "student"), and reconstruct the held-out demonstrations
(``rollouts`` origin student, ``contacts`` source reconstructed, ``student_predictions``)."""

from __future__ import annotations

import dataclasses

from prefect import flow

from tasks.common import stored
from tasks.ingest import refresh_catalog
from tasks.runners import ProfileTaskRunner
from tasks.student import augment_dataset, reconstruct, report_student, train_student
from touch2robot import datasets
from touch2robot.config import load_profile
from touch2robot.settings import DataLayout
from touch2robot.student.augment import split_demonstrations


@flow(name="student", task_runner=ProfileTaskRunner(section="training_runner"), log_prints=True)
def student(profile: str = "smoke", data: str | None = None, variants: list[str] | None = None) -> dict:
    """Dataset -> one training per variant (default: full and the profile's ablations) ->
    reconstructions of the held-out demonstrations of every task with teacher rollouts."""
    layout = DataLayout.from_env(data)
    prof = load_profile(profile)
    config, teacher = prof.student, prof.teacher
    variants = list(variants or config.variants)
    for v in variants:
        config.variant(v)  # an unknown variant fails here, before any training
    recordings = datasets.taught_demonstrations(layout.lake, config.teacher_method)
    if not recordings:
        print(
            f"student: no teacher rollouts of {config.teacher_method} in {datasets.ROLLOUTS.folder(layout.lake)}: "
            "run the teachers flow first"
        )
        return {}
    demos: dict[str, list[str]] = {}
    for r in recordings:
        demos.setdefault(r["task"], []).append(r["recording_id"])
    split = dataclasses.asdict(split_demonstrations(demos, config.held_out_fraction, config.val_fraction, config.seed))
    sources = [datasets.teacher_rollouts(layout.lake, config.teacher_method, t) for t in sorted(demos)]
    digest = datasets.references_digest(layout.lake, recordings) + "".join(datasets.file_digest(p) for p in sources)
    root = str(layout.root)
    dataset = stored(augment_dataset, layout.results)(config, teacher, split, recordings, digest, root, profile)
    trained = [
        stored(train_student, layout.results).submit(v, config, teacher, dataset, root, profile) for v in variants
    ]
    rebuilt = [
        stored(reconstruct, layout.results).submit(t, config, teacher, split, recordings, digest, root) for t in trained
    ]
    trained_rows = [f.result() for f in trained]
    rows = [r for f in rebuilt for r in f.result()]
    refresh_catalog(root)
    report_student(profile, trained_rows, rows)
    for t in trained_rows:
        print(
            f"student {t['variant']:12s} val loss {t['initial_val_loss']:.4f} -> {t['final_val_loss']:.4f} "
            f"({t['steps']} updates)"
        )
    for r in rows:
        print(
            f"student {r['variant']:12s} {r['task']:7s} joint error {r['joint_error_student']:.4f} rad "
            f"(kinematic input {r['joint_error_kinematic']:.4f}), "
            f"contact F1 {r['contact_f1']:.3f} (predicted {r['predicted_contact_f1']:.3f})"
        )
    return {"split": split, "trained": trained_rows, "heldout": rows}
