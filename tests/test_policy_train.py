"""LeRobot's Diffusion Policy on a dataset of real MuJoCo rollouts: a few updates lower the loss,
training resumes from LeRobot's last checkpoint, the closed loop predicts 24 actions and executes 16
before replanning, and the `policy` flow fills ``policy_eval`` and its MLflow runs."""

from __future__ import annotations

import shutil
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import lerobot_frame, scripted_rollout_rows

from touch2robot import lake as lake_io
from touch2robot.config import load_profile
from touch2robot.policy.dataset import ENVIRONMENT_NAMES, build_dataset, read_rollouts, sources
from touch2robot.policy.evaluate import action_fit, episode_starts, load_policy, replay_demonstrations, rollout_policy
from touch2robot.policy.train import last_checkpoint, train
from touch2robot.sim.config import SimConfig
from touch2robot.sim.scene import build_scene

CONFIG = load_profile("smoke").policy


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory):
    torch.set_num_threads(1)
    base = tmp_path_factory.mktemp("policy-train")
    lake_io.write_rows(
        base / "lake",
        "rollouts",
        "teacher-pick-seed0",
        scripted_rollout_rows("pick", "touch2robot", 4, 30),
        partition={"method": "touch2robot"},
    )
    src = sources(base / "lake")[0]
    sim = SimConfig(threads=1)
    rollouts = read_rollouts(src.path)
    summary = build_dataset(base / "ds", "pick", "touch2robot", rollouts, build_scene("pick", sim), sim, CONFIG)
    logs: list[tuple[int, dict]] = []
    # checkpoints every 8 updates: test_a_resumed_training_equals_the_uninterrupted_one resumes from two
    saving = CONFIG.model_copy(update={"save_freq": 8, "keep_checkpoints": 10})
    result = train(Path(summary.root), summary.repo_id, saving, base / "out", on_log=lambda s, m: logs.append((s, m)))
    return summary, rollouts, result, logs, base


def test_a_few_updates_lower_the_loss(trained) -> None:
    _, _, result, logs, _ = trained
    assert result.steps == CONFIG.steps and result.resumed_from == 0
    assert [s for s, _ in logs] == list(range(CONFIG.log_freq, CONFIG.steps + 1, CONFIG.log_freq))
    assert result.last_loss < result.first_loss - 0.02, [m["loss"] for _, m in logs]
    assert logs[-1][1]["lr"] < logs[0][1]["lr"]  # LeRobot's cosine schedule decays
    assert (Path(result.policy_dir) / "model.safetensors").is_file()


def test_training_resumes_from_the_last_checkpoint(trained) -> None:
    summary, _, _, _, base = trained
    checkpoint = last_checkpoint(base / "out")
    assert checkpoint is not None and checkpoint.name == f"{CONFIG.steps:06d}"
    keeping = CONFIG.model_copy(update={"keep_checkpoints": 10})  # the checkpoints the next test resumes from
    more = train(Path(summary.root), summary.repo_id, keeping, base / "out", steps=CONFIG.steps + CONFIG.log_freq)
    assert more.resumed_from == CONFIG.steps and more.steps == CONFIG.steps + CONFIG.log_freq
    assert np.isfinite(more.last_loss)


@pytest.mark.parametrize("crashed_at", [24, 32])
def test_a_resumed_training_equals_the_uninterrupted_one(trained, crashed_at: int, tmp_path: Path) -> None:
    """Resuming from a checkpoint gives the bits of the training that was never stopped, whether it
    stopped at the end of an epoch (step 24) or within one (step 32): a local cell trained across
    sessions is the cell trained at once."""
    from lerobot.datasets import compute_sampler_state
    from safetensors.torch import load_file

    summary, _, result, _, base = trained
    sampled = summary.frames - summary.episodes * (CONFIG.horizon - CONFIG.n_action_steps - CONFIG.n_obs_steps + 1)
    assert compute_sampler_state(crashed_at, sampled, CONFIG.batch_size, 1) == (
        {"epoch": 2, "start_index": 0} if crashed_at == 24 else {"epoch": 2, "start_index": 64}
    )
    checkpoints = tmp_path / "resumed" / "checkpoints"
    shutil.copytree(base / "out" / "checkpoints" / f"{crashed_at:06d}", checkpoints / f"{crashed_at:06d}")
    (checkpoints / "last").symlink_to(f"{crashed_at:06d}")
    resumed = train(Path(summary.root), summary.repo_id, CONFIG, tmp_path / "resumed")
    assert (resumed.resumed_from, resumed.steps) == (crashed_at, CONFIG.steps)
    whole, pieced = (load_file(Path(r.policy_dir) / "model.safetensors") for r in (result, resumed))
    assert whole.keys() == pieced.keys()
    assert [name for name in whole if not torch.equal(whole[name], pieced[name])] == []


def test_a_time_budget_or_a_stop_ends_training_early_with_a_checkpoint_to_resume_from(trained) -> None:
    summary, _, _, _, base = trained
    total = 10 * CONFIG.steps
    cut = train(Path(summary.root), summary.repo_id, CONFIG, base / "timed", steps=total, max_seconds=0.0)
    assert cut.steps == 1 and np.isfinite(cut.last_loss)
    assert last_checkpoint(base / "timed") == Path(cut.policy_dir).parent
    logs: list[tuple[int, dict]] = []
    more = train(
        Path(summary.root),
        summary.repo_id,
        CONFIG,
        base / "timed",
        steps=total,
        on_log=lambda s, m: logs.append((s, m)),
        should_stop=lambda: True,
    )
    assert more.resumed_from == 1 and more.steps == 2
    # policy.keep_checkpoints (1): the first call's checkpoint went once the second's was complete
    kept = sorted(p.name for p in (base / "timed" / "checkpoints").iterdir())
    assert kept == [Path(more.policy_dir).parent.name, "last"]
    # the learning rate follows the schedule of ``total`` updates: right after the smoke profile's
    # 2 warm-up updates it is at its peak (a schedule of 2 updates would have decayed it to 0)
    assert CONFIG.scheduler_warmup_steps == 2 and [s for s, _ in logs] == [2]
    assert logs[0][1]["lr"] == pytest.approx(CONFIG.lr)
    # a call on the finished folder does no update and still reports the training's losses
    again = train(Path(summary.root), summary.repo_id, CONFIG, base / "timed", steps=2)
    assert (again.resumed_from, again.steps) == (2, 2) and np.isnan(again.samples_per_s)
    assert (again.first_loss, again.last_loss) == (cut.first_loss, more.last_loss)


def test_training_where_cuda_is_available_logs_the_peak_gpu_memory(
    trained, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """LeRobot's update step records the peak GPU memory wherever CUDA is available, into a meter
    the training loop must provide: without it every training on a GPU machine stopped at its first
    update (seen on an H200). Here the CPU runs the updates and only LeRobot's update step is told
    that CUDA is there."""
    from lerobot.scripts import lerobot_train

    class TorchWithCuda(types.ModuleType):
        cuda = types.SimpleNamespace(
            is_available=lambda: True, max_memory_allocated=lambda: 3 * 2**30, reset_peak_memory_stats=lambda: None
        )

        def __getattr__(self, name: str):
            return getattr(torch, name)

    monkeypatch.setattr(lerobot_train, "torch", TorchWithCuda("torch"))
    summary = trained[0]
    logs: list[tuple[int, dict]] = []
    cfg = CONFIG.model_copy(update={"log_freq": 1})
    result = train(
        Path(summary.root), summary.repo_id, cfg, tmp_path / "out", steps=2, on_log=lambda s, m: logs.append((s, m))
    )
    assert result.steps == 2
    assert [m["gpu_mem_gb"] for _, m in logs] == [3.0, 3.0]


def test_closed_loop_executes_16_predicted_actions_then_replans(trained, monkeypatch: pytest.MonkeyPatch) -> None:
    _, rollouts, result, _, _ = trained
    sim = SimConfig(threads=1)
    scene = build_scene("pick", sim)
    policy, pre, post = load_policy(Path(result.policy_dir), "cpu")
    assert (policy.config.horizon, policy.config.n_action_steps, policy.config.n_obs_steps) == (
        24,
        16,
        CONFIG.n_obs_steps,
    )
    chunks: list[torch.Tensor] = []
    predict = policy.predict_action_chunk

    def recording(batch):
        out = predict(batch)
        chunks.append(out)
        return out

    monkeypatch.setattr(policy, "predict_action_chunk", recording)
    starts = episode_starts(scene, rollouts, 1, seed=3, object_noise_m=CONFIG.object_noise_m)
    out = rollout_policy(policy, pre, post, scene, sim, starts, CONFIG, video_episodes=1, steps=40)
    assert out.steps == 40 and out.replans == 3 == len(chunks)  # steps 0, 16, 32
    assert all(c.shape == (1, 16, 23) for c in chunks)
    assert out.success.shape == (1,) and 0.0 <= out.progress[0] <= 1.0
    assert out.videos[0].shape == (40, CONFIG.image_size, 2 * CONFIG.image_size, 3)
    torch.manual_seed(123)  # the evaluation seeds its own diffusion noise: the global seed does not matter
    rollout_policy(policy, pre, post, scene, sim, starts, CONFIG, steps=16)
    assert torch.equal(chunks[3], chunks[0])


def test_action_fit_compares_the_executed_steps_with_the_recorded_actions(trained) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    summary, _, result, _, _ = trained
    policy, pre, post = load_policy(Path(result.policy_dir), "cpu")
    fit = action_fit(policy, pre, post, Path(summary.root), summary.repo_id, frames=10_000)
    assert fit.frames == summary.frames  # every frame, once
    # holding still, computed here from the plain frames: the executed steps are the frame's own
    # and the next n_action_steps - 1 of its episode, none past the episode's end
    ds = LeRobotDataset(summary.repo_id, root=summary.root)
    joint, wrist = [], []
    for ep in range(ds.num_episodes):
        frames = [f for f in (lerobot_frame(ds, i) for i in range(len(ds))) if int(f["episode_index"]) == ep]
        state = np.stack([f["observation.state"].numpy() for f in frames])
        action = np.stack([f["action"].numpy() for f in frames])
        for t in range(len(frames)):
            diff = np.abs(action[t : t + CONFIG.n_action_steps] - state[t])
            joint.append(diff[:, :16])
            wrist.append(diff[:, 16:19])
    assert fit.hold_joint_err_rad == pytest.approx(np.concatenate(joint).mean(), rel=1e-4)
    assert fit.hold_wrist_err_mm == pytest.approx(1000 * np.concatenate(wrist).mean(), rel=1e-4)
    assert 0 < fit.joint_err_rad < np.inf and 0 < fit.wrist_err_mm < np.inf
    assert action_fit(policy, pre, post, Path(summary.root), summary.repo_id, frames=10_000) == fit  # seeded


def test_a_state_policy_sees_no_camera_learns_and_runs_closed_loop_with_a_filmed_episode(
    trained, tmp_path: Path
) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    summary, rollouts, _, _, _ = trained
    cfg = CONFIG.model_copy(update={"observation": "state", "steps": 60})
    sim = SimConfig(threads=1)
    scene = build_scene("pick", sim)
    state = build_dataset(tmp_path / "ds", "pick", "touch2robot", rollouts, scene, sim, cfg)
    assert state.render_frames == 0 and state.frames == summary.frames
    ds = LeRobotDataset(state.repo_id, root=state.root)  # LeRobot's own loader reads it
    assert not ds.meta.camera_keys
    assert ds.meta.features["observation.environment_state"]["names"] == list(ENVIRONMENT_NAMES["state"])
    frame, r = lerobot_frame(ds, 31), rollouts[1]  # episode 1, step 1
    np.testing.assert_allclose(frame["observation.environment_state"][8:15].numpy(), r.object_pose[1], atol=1e-5)
    assert frame["observation.environment_state"][15] == 0  # no drawer in pick
    np.testing.assert_allclose(frame["action"].numpy(), np.concatenate([r.joint_target[1], r.wrist_pose[1]]), atol=1e-6)
    logs: list[float] = []
    result = train(Path(state.root), state.repo_id, cfg, tmp_path / "out", on_log=lambda s, m: logs.append(m["loss"]))
    assert result.last_loss < result.first_loss - 0.02, logs
    policy, pre, post = load_policy(Path(result.policy_dir), "cpu")
    environment = policy.config.env_state_feature
    assert not policy.config.image_features and environment is not None and environment.shape == (16,)
    assert policy.config.normalization_mapping["ENV"].value == "MIN_MAX"
    starts = episode_starts(scene, rollouts, 2, seed=3, object_noise_m=cfg.object_noise_m)
    out = rollout_policy(policy, pre, post, scene, sim, starts, cfg, video_episodes=1, steps=20)
    assert out.replans == 2 and out.success.shape == (2,)
    # no camera drives it, yet the profile's cameras film the recorded episode
    assert len(out.videos) == 1 and out.videos[0].shape == (20, cfg.image_size, 2 * cfg.image_size, 3)
    assert out.videos[0].std() > 1


def test_replayed_demonstrations_reproduce_their_rollouts(tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    # scripted drawer pulls: each copy opens the drawer by its own amount, so progress tells them apart
    path = lake_io.write_rows(
        tmp_path / "lake",
        "rollouts",
        "teacher-drawer-seed0",
        scripted_rollout_rows("drawer", "contrack", 4, 30),
        partition={"method": "contrack"},
    )
    rollouts = read_rollouts(path)
    sim = SimConfig(threads=1)
    scene = build_scene("drawer", sim)
    starts = episode_starts(scene, rollouts, 6, seed=0, object_noise_m=CONFIG.object_noise_m)
    steps = len(rollouts[0]) - 1  # the state after T-1 commands is the rollout's last row
    out = replay_demonstrations(scene, sim, starts, CONFIG.model_copy(update={"eval_batch": 4}), steps=steps)
    last = {
        r["rollout_id"]: r["progress"]
        for r in pq.read_table(path, columns=["rollout_id", "step", "progress"]).to_pylist()
        if r["step"] == steps
    }
    assert len(set(last.values())) == 4 and len(set(starts.source)) > 1
    assert out.steps == steps and out.replans == 0
    np.testing.assert_allclose(out.progress, [last[i] for i in starts.source], atol=1e-9)


@pytest.mark.slow
def test_policy_flow_fills_policy_eval_and_mlflow(tmp_path: Path) -> None:
    import mlflow

    from flows.policy import policy
    from tasks import tracking
    from touch2robot import catalog
    from touch2robot.settings import DataLayout

    layout = DataLayout(tmp_path / "data")
    lake_io.write_rows(
        layout.lake,
        "rollouts",
        "teacher-pick-seed0",
        scripted_rollout_rows("pick", "contrack", 2, 24),
        partition={"method": "contrack"},
    )
    lake_io.write_rows(
        layout.lake,
        "rollouts",
        "teacher-pick-seed0",
        scripted_rollout_rows("pick", "dexmachina", 2, 24),
        partition={"method": "dexmachina"},
    )
    rows = policy(profile="smoke", data=str(layout.root), methods=["contrack"])  # the filter leaves one of the two
    assert [(r["task"], r["method"], r["origin"], r["episodes"], r["dataset_episodes"]) for r in rows] == [
        ("pick", "contrack", "teacher", CONFIG.eval_episodes, 2)
    ]
    table = catalog.query(
        layout,
        "SELECT task, method, episodes, ci_low <= success_rate AND success_rate <= ci_high AS inside, "
        "fit_wrist_err_mm > 0 AND hold_wrist_err_mm > 0 AS fitted, replay_successes BETWEEN 0 AND episodes AS replayed "
        "FROM policy_eval",
    )
    assert table.to_pylist() == [
        {
            "task": "pick",
            "method": "contrack",
            "episodes": CONFIG.eval_episodes,
            "inside": True,
            "fitted": True,
            "replayed": True,
        }
    ]
    tracking.experiment(layout, "policy")
    run = mlflow.get_run(rows[0]["mlflow_run"])
    assert {"train/loss", "eval/success_rate", "fit/wrist_err_mm", "fit/hold_wrist_err_mm"} <= set(run.data.metrics)
    assert run.data.tags["pretrained_backbone"].startswith("none")
    artefacts = {a.path for a in mlflow.MlflowClient().list_artifacts(run.info.run_id)}
    assert {"policy", "videos"} <= artefacts
    again = policy(profile="smoke", data=str(layout.root), methods=["contrack"])  # cached: the same rows, no retraining
    assert again == rows


@pytest.mark.slow
def test_a_policy_trained_beside_another_equals_it_trained_alone(tmp_path: Path) -> None:
    """The fan-out must not change a result: LeRobot draws its batches, noise and crops from
    torch's RNG, which a process shares between its threads, so two trainings side by side in one
    process would take turns on it and neither would repeat. Training runs one process each."""
    import yaml

    from flows.policy import policy
    from touch2robot.settings import DataLayout

    # the smoke profile with fewer updates: any interleaving shows from the first batch on
    smoke = yaml.safe_load((Path(__file__).parents[1] / "touch2robot" / "profiles" / "smoke.yaml").read_text())
    smoke["policy"].update(steps=10, save_freq=10, log_freq=5, eval_episodes=1, eval_batch=1, video_episodes=0)
    profile = tmp_path / "short.yaml"
    profile.write_text(yaml.safe_dump(smoke))
    rows = {}
    for name, methods in (("alone", ["contrack"]), ("paired", ["contrack", "dexmachina"])):
        layout = DataLayout(tmp_path / name)
        for method in ("contrack", "dexmachina"):
            lake_io.write_rows(
                layout.lake,
                "rollouts",
                "teacher-pick-seed0",
                scripted_rollout_rows("pick", method, 2, 24),
                partition={"method": method},
            )
        out = policy(profile=str(profile), data=str(layout.root), methods=methods)
        rows[name] = next({k: v for k, v in r.items() if k != "mlflow_run"} for r in out if r["method"] == "contrack")
    assert rows["paired"]["final_loss"] == rows["alone"]["final_loss"]
    assert rows["paired"] == rows["alone"]
