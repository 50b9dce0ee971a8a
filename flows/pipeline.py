"""Flow `pipeline`: every stage that exists, in order, on one profile."""

from __future__ import annotations

from prefect import flow

from flows.evaluate import evaluate
from flows.ingest import ingest
from flows.policy import policy
from flows.retarget import retarget
from flows.student import student
from flows.synth import synth
from flows.teachers import teachers


@flow(name="pipeline", log_prints=True)
def pipeline(profile: str = "smoke", data: str | None = None, synthesize: bool = True) -> dict:
    """Simulated demonstrator (unless ``synthesize`` is false: bring your own recordings
    in ``<data>/recordings``) -> ingest and contacts -> kinematic retargeting -> teachers and
    their rollouts -> the distilled student and its reconstructions -> contact evaluation ->
    robot-demonstration datasets, Diffusion Policies and their closed-loop success."""
    if synthesize:
        synth(profile=profile, data=data)
    ingested = ingest(profile=profile, data=data)
    retargeted = retarget(profile=profile, data=data)
    taught = teachers(profile=profile, data=data)
    distilled = student(profile=profile, data=data)
    evaluated = evaluate(profile=profile, data=data)
    policies = policy(profile=profile, data=data)
    return {
        "ingest": ingested,
        "retarget": retargeted,
        "teachers": taught,
        "student": distilled,
        "evaluate": evaluated,
        "policy": policies,
    }
