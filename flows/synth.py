"""Flow `synth`: the simulated demonstrator writes a profile's recordings."""

from __future__ import annotations

from prefect import flow, unmapped

from tasks.common import stored
from tasks.runners import ProfileTaskRunner
from tasks.synth import synthesize_ratings, synthesize_recording, write_default_rig
from touch2robot.config import load_profile
from touch2robot.settings import DataLayout
from touch2robot.synth.generate import plan


@flow(name="synth", task_runner=ProfileTaskRunner(), log_prints=True)
def synth(profile: str = "smoke", data: str | None = None) -> list[str]:
    """Write the profile's glove sessions, the rig file they were recorded with and the synthetic
    user-study ratings under ``<data>/recordings`` (ground truth under ``<data>/groundtruth``)."""
    layout = DataLayout.from_env(data)
    config = load_profile(profile).synth
    write_default_rig(str(layout.recordings))
    write = stored(synthesize_recording, layout.results)
    futures = write.map(
        unmapped(config), plan(config), unmapped(str(layout.recordings)), unmapped(str(layout.groundtruth))
    )
    ratings = stored(synthesize_ratings, layout.results).submit(str(layout.synthetic_ratings), config.seed)
    paths = [f.result() for f in futures]
    ratings.result()
    print(f"{len(paths)} recordings in {layout.recordings}")
    return paths
