"""Profiles are typed data files; bad ones fail with the file and field named."""

from __future__ import annotations

from pathlib import Path

import pytest

from touch2robot.config import BUILTIN_PROFILES, ProfileError, load_profile


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_builtin_profiles_load(name: str) -> None:
    profile = load_profile(name)
    assert profile.name == name


def test_paper_profile_is_the_code_defaults() -> None:
    paper = load_profile("paper")
    assert paper.synth.subjects * paper.synth.demos_per_subject == 30


def test_the_paper_policy_is_table_ix_whatever_the_small_profiles_do() -> None:
    from touch2robot.policy.dataset import FPS, features
    from touch2robot.policy.train import diffusion_kwargs

    policy = load_profile("paper").policy
    # Table IX: 20 Hz, 2 RGB views 224x224, 5 observation steps, horizon 24, 16 executed, Adam lr 1e-4,
    # weight decay 1e-6, batch 64, 50,000 updates; everything else LeRobot's default
    assert FPS == 20 and policy.observation == "images" and len(policy.cameras) == 2
    views = [k for k, f in features(policy).items() if f["dtype"] == "image"]
    assert len(views) == 2 and all(features(policy)[k]["shape"] == (224, 224, 3) for k in views)
    assert (policy.n_obs_steps, policy.horizon, policy.n_action_steps) == (5, 24, 16)
    assert (policy.lr, policy.weight_decay, policy.batch_size, policy.steps) == (1e-4, 1e-6, 64, 50_000)
    assert policy.down_dims is None and policy.num_inference_steps is None and policy.scheduler_warmup_steps is None
    assert "normalization_mapping" not in diffusion_kwargs(policy)  # LeRobot's own
    assert load_profile("local").policy.observation == "state"  # the laptop's policy sees no camera


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("synth:\n  subjects: 0\n", "synth.subjects"),
        ("synth:\n  subjcts: 2\n", "synth.subjcts"),
        ("contacts: [1, 2]\n", "contacts"),
        ("synth: {subjects: 2\n", "not valid YAML"),
        ("- a\n- b\n", "expected a mapping"),
        ("training_runner:\n  kind: threads\n", "training_runner.kind 'threads'"),
        ("training_runner:\n  kind: dask\n  threads_per_worker: 2\n", "training_runner.threads_per_worker"),
        ("", "the profile is empty"),
        ("# only a comment\n", "the profile is empty"),
        ("teacher:\n  sim:\n    n_envs: true\n", "teacher.sim.n_envs: expected a number, got True"),
        ("teacher:\n  ppo:\n    learning_rate: false\n", "teacher.ppo.learning_rate: expected a number"),
        ("teacher:\n  ppo:\n    hidden_dims: [64, true]\n", "teacher.ppo.hidden_dims.1: expected a number"),
        ("synth:\n  subjects: 2\n  subjects: 3\n", "duplicate key 'subjects' (first at line 2)"),
        ("policy:\n  image_size: 8\n", "policy.image_size"),
        ("twin:\n  latency_s: [0.0, 5.0]\n", "twin.latency_s.1: Input should be less than or equal to 0.2"),
        ("twin:\n  kp_scale: [1.2, 0.8]\n", "twin: Value error, kp_scale: low 1.2 is above high 0.8"),
        ("twin:\n  friction_scale: [true, 1.0]\n", "twin.friction_scale.0: expected a number, got True"),
        ("replay:\n  demos_per_task: 0\n", "replay.demos_per_task"),
        ("replay:\n  touch2robot_origin: kinematic\n", "replay.touch2robot_origin"),
        ("seeds: [0, 1, 1]\n", "seeds: Value error, seed 1 is given 2 times"),
        ("seeds: [0, -3]\n", "seeds: Value error, seeds are whole numbers >= 0, got -3"),
        ("seeds: []\n", "seeds: Value error, give at least one seed"),
        ("seeds: [0, true]\n", "seeds.1: expected a number, got True"),
    ],
)
def test_bad_profile_names_file_and_field(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "mine.yaml"
    path.write_text(text)
    with pytest.raises(ProfileError, match=r"mine\.yaml") as err:
        load_profile(path)
    assert message in str(err.value)


def test_unknown_profile_name() -> None:
    with pytest.raises(ProfileError, match="unknown profile 'tiny'"):
        load_profile("tiny")


def test_a_sweep_seed_moves_every_stochastic_stage_and_keeps_the_held_out_split() -> None:
    profile = load_profile("smoke")
    assert profile.seeds == (0,) and profile.for_seed(0) == profile  # seed 0 is the profile as written
    second = profile.for_seed(2)
    assert second.teacher.seed == profile.teacher.seed + 2
    assert second.student.seed == profile.student.seed + 2
    assert second.replay.seed == profile.replay.seed + 2
    assert second.policy.seed == profile.policy.seed + 2
    # two seeds' evaluation episodes never coincide: whole episode sets apart
    assert second.policy.eval_seed == profile.policy.eval_seed + 2 * profile.policy.eval_episodes
    assert second.synth == profile.synth and second.retarget == profile.retarget and second.contacts == profile.contacts
    assert profile.sweep([3, 1]) == (3, 1) and profile.sweep(None) == (0,)
    for bad, message in (([1, 1], "seed 1 is given 2 times"), ([-1], "whole numbers >= 0"), ([], "at least one")):
        with pytest.raises(ValueError, match=rf"--seeds: .*{message}"):
            profile.sweep(bad)
