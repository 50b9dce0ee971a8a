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
def student(
    profile: str = "smoke", data: str | None = None, variants: list[str] | None = None, seeds: list[int] | None = None
) -> dict:
    """Dataset -> one training per variant (default: full and the profile's ablations) ->
    reconstructions of the held-out demonstrations of every task with teacher rollouts; once per
    sweep seed (``seeds``, default the profile's), on the held-out split of ``student.seed``."""
    layout = DataLayout.from_env(data)
    prof = load_profile(profile)
    sweep = prof.sweep(seeds)
    variants = list(variants or prof.student.variants)
    for v in variants:
        prof.student.variant(v)  # an unknown variant fails here, before any training
    root = str(layout.root)
    split = None
    trained, rebuilt = [], []
    for seed in sweep:
        seeded = prof.for_seed(seed)
        config, teacher = seeded.student, seeded.teacher
        recordings = datasets.taught_demonstrations(layout.lake, config.teacher_method, seed)
        if not recordings:
            print(
                f"student: no teacher rollouts of {config.teacher_method} of seed {seed} in "
                f"{datasets.ROLLOUTS.folder(layout.lake)}: run the teachers flow first"
            )
            continue
        demos: dict[str, list[str]] = {}
        for r in recordings:
            demos.setdefault(r["task"], []).append(r["recording_id"])
        # one split for every sweep seed: the seeds differ in training, not in what they are scored on
        seed_split = dataclasses.asdict(
            split_demonstrations(demos, config.held_out_fraction, config.val_fraction, prof.student.seed)
        )
        split = split or seed_split
        sources = [datasets.teacher_rollouts(layout.lake, config.teacher_method, t, seed) for t in sorted(demos)]
        digest = datasets.references_digest(layout.lake, recordings) + "".join(datasets.file_digest(p) for p in sources)
        dataset = stored(augment_dataset, layout.results)(
            seed, config, teacher, seed_split, recordings, digest, root, profile
        )
        seed_trained = [
            stored(train_student, layout.results).submit(v, config, teacher, dataset, root, profile) for v in variants
        ]
        rebuilt += [
            stored(reconstruct, layout.results).submit(t, config, teacher, seed_split, recordings, digest, root)
            for t in seed_trained
        ]
        trained += seed_trained
    if split is None:
        return {}
    trained_rows = [f.result() for f in trained]
    rows = [r for f in rebuilt for r in f.result()]
    refresh_catalog(root)
    report_student(profile, trained_rows, rows)
    for t in trained_rows:
        print(
            f"student {t['variant']:12s} seed {t['seed']} val loss {t['initial_val_loss']:.4f} -> "
            f"{t['final_val_loss']:.4f} ({t['steps']} updates)"
        )
    for r in rows:
        print(
            f"student {r['variant']:12s} seed {r['seed']} {r['task']:7s} joint error "
            f"{r['joint_error_student']:.4f} rad (kinematic input {r['joint_error_kinematic']:.4f}), "
            f"contact F1 {r['contact_f1']:.3f} (predicted {r['predicted_contact_f1']:.3f})"
        )
    return {"split": split, "trained": trained_rows, "heldout": rows}
