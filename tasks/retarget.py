"""Tasks of kinematic retargeting: one cached task per glove recording (lake rows, MLflow run,
comparison drawing) and a Prefect artefact summarising the flow run."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from prefect import get_run_logger, task
from prefect.artifacts import create_markdown_artifact, create_table_artifact

from tasks import tracking
from tasks.common import ALWAYS_RUN, cache_policy
from touch2robot import datasets
from touch2robot import lake as lake_io
from touch2robot.retarget import RetargetConfig
from touch2robot.settings import DataLayout

if TYPE_CHECKING:  # the retargeter imports torch: loaded only when a task runs
    from touch2robot.retarget.retargeter import RetargetResult

# Residual columns in the order of the robot fingertips (regions T1..T4).
TIP_NAMES = ("thumb", "index", "middle", "ring")


def _summary(result: RetargetResult) -> dict:
    """The figures of one result that the MLflow run and the flow's artefact show."""
    from touch2robot.retarget.retargeter import STATUS_NAMES

    ok = result.residual[np.isfinite(result.residual).all(axis=1)]
    step = np.abs(np.diff(result.joints, axis=0)).max(axis=1) if len(result.t) > 1 else np.zeros(1)
    return {
        "frames": len(result.t),
        "failed_frames": int(result.failed.sum()),
        **{f"status_{name}": int((result.status == code).sum()) for code, name in enumerate(STATUS_NAMES) if code},
        "residual_mean_mm": float(1e3 * ok.mean()) if ok.size else float("nan"),
        "residual_p95_mm": float(1e3 * np.percentile(ok, 95)) if ok.size else float("nan"),
        "residual_max_mm": float(1e3 * ok.max()) if ok.size else float("nan"),
        **{
            f"residual_mean_{f}_mm": float(1e3 * ok[:, i].mean()) if ok.size else float("nan")
            for i, f in enumerate(TIP_NAMES)
        },
        "solve_ms_mean": float(1e3 * result.solve_time.mean()),
        "solve_ms_p95": float(1e3 * np.percentile(result.solve_time, 95)),
        "max_joint_step_rad": float(step.max()),
        "scaling": result.scaling,
    }


@task(
    cache_policy=cache_policy("touch2robot.retarget", "touch2robot.leap", "touch2robot.lake", "touch2robot.datasets"),
    persist_result=True,
    retries=1,
    task_run_name="retarget-{recording[recording_id]}",
)
def retarget_recording(recording: dict, config: RetargetConfig, data: str, profile: str, render: bool = False) -> dict:
    """Retarget one ingested glove recording into the ``retargeted`` table, with an MLflow run
    (stage "retarget") and, if ``render``, a drawing of human vs robot over a few frames. Hand
    motion that cannot be retargeted is reported (``error``) and leaves no rows, like a
    quarantined file."""
    from touch2robot.retarget.lake import load_hand_motion, result_rows
    from touch2robot.retarget.retargeter import HandMotionError, Retargeter, retarget_motion

    layout = DataLayout.from_env(data)
    rid = recording["recording_id"]
    name = Path(recording["path"]).stem
    base = {"recording_id": rid, "file": name, "task": recording["task"]}
    try:
        motion = load_hand_motion(layout.lake, rid, config)
    except HandMotionError as e:
        get_run_logger().warning("not retargeted: %s", e)
        lake_io.remove(datasets.RETARGETED.path(layout.lake, datasets.RecordingKey(rid)))
        return {**base, "error": str(e)}
    retargeter = Retargeter(config)
    result = retarget_motion(motion, config, retargeter)
    datasets.RETARGETED.write(layout.lake, datasets.RecordingKey(result.recording_id), result_rows(result))
    summary = _summary(result)
    tags = {"profile": profile, "recording_id": rid, "task": recording["task"] or "", "file": name}
    with tracking.stage_run(layout, "retarget", f"retarget-{name}", tags) as run:
        import mlflow

        mlflow.log_params(config.model_dump(mode="json"))
        mlflow.log_metrics(summary)
        if render:
            from touch2robot.retarget.render import comparison_png

            with tempfile.TemporaryDirectory() as tmp:
                png = comparison_png(
                    motion, result, Path(tmp) / f"retarget_{name}.png", kinematics=retargeter.kinematics
                )
                mlflow.log_artifact(str(png), "comparison")
        run_id = run.info.run_id
    if summary["failed_frames"]:
        get_run_logger().warning(
            "%s: %d of %d frames failed and hold the previous solution",
            name,
            summary["failed_frames"],
            summary["frames"],
        )
    return {**base, "error": "", "mlflow_run": run_id, **summary}


@task(**ALWAYS_RUN)
def report_retarget(profile: str, results: list[dict]) -> dict:
    """A Prefect table and summary of the flow run; returns the aggregate figures."""
    done = [r for r in results if not r["error"]]
    frames = sum(r["frames"] for r in done)
    agg = {
        "recordings": len(done),
        "not_retargeted": len(results) - len(done),
        "frames": frames,
        "failed_frames": sum(r["failed_frames"] for r in done),
        # frame-weighted mean; the 95th percentile is the worst recording's
        "residual_mean_mm": sum(r["residual_mean_mm"] * r["frames"] for r in done) / frames if frames else float("nan"),
        "residual_p95_mm_worst": max((r["residual_p95_mm"] for r in done), default=float("nan")),
        "solve_ms_mean": sum(r["solve_ms_mean"] * r["frames"] for r in done) / frames if frames else float("nan"),
    }
    create_table_artifact(
        key="retarget-recordings",
        table=[
            {
                k: (round(v, 2) if isinstance(v, float) else v)
                for k, v in r.items()
                if k
                in (
                    "file",
                    "task",
                    "frames",
                    "failed_frames",
                    "residual_mean_mm",
                    "residual_p95_mm",
                    "max_joint_step_rad",
                    "solve_ms_mean",
                    "error",
                )
            }
            for r in results
        ],
        description="Kinematic retargeting per glove recording",
    )
    create_markdown_artifact(
        key="retarget-summary",
        markdown=(
            f"# Retarget ({profile})\n\n| recordings | not retargeted | frames | failed frames | mean residual "
            "(mm) | worst p95 (mm) | solve (ms/frame) |\n"
            f"|---|---|---|---|---|---|---|\n| {agg['recordings']} | {agg['not_retargeted']} | {frames} | "
            f"{agg['failed_frames']} | "
            f"{agg['residual_mean_mm']:.2f} | {agg['residual_p95_mm_worst']:.2f} | {agg['solve_ms_mean']:.2f} |\n\n"
            + "".join(f"- not retargeted `{r['file']}`: {r['error']}\n" for r in results if r["error"])
        ),
    )
    return agg
