"""Flow `pipeline`: every stage that exists, in order, on one profile."""

from __future__ import annotations

from statistics import fmean

import pandas as pd
from prefect import flow

from flows.evaluate import evaluate
from flows.ingest import ingest
from flows.policy import policy
from flows.replay import replay
from flows.report import report
from flows.retarget import retarget
from flows.student import student
from flows.synth import synth
from flows.teachers import teachers
from schemas.vocabulary import Origin, Source
from touch2robot.config import load_profile
from touch2robot.report import as_text, pooled_policy


@flow(name="pipeline", log_prints=True)
def pipeline(
    profile: str = "smoke", data: str | None = None, synthesize: bool = True, seeds: list[int] | None = None
) -> dict:
    """Simulated demonstrator (unless ``synthesize`` is false: bring your own recordings
    in ``<data>/recordings``) -> ingest and contacts -> kinematic retargeting -> teachers and
    their rollouts -> the distilled student and its reconstructions -> every method's trajectories
    replayed on the hardware twin and ingested -> contact evaluation ->
    robot-demonstration datasets, Diffusion Policies and their closed-loop success -> the report.
    The stochastic stages run once per sweep seed (``seeds``, default the profile's)."""
    load_profile(profile).sweep(seeds)  # a bad profile or seed list fails here, before any compute
    if synthesize:
        synth(profile=profile, data=data)
    ingested = ingest(profile=profile, data=data)
    retargeted = retarget(profile=profile, data=data)
    taught = teachers(profile=profile, data=data, seeds=seeds)
    distilled = student(profile=profile, data=data, seeds=seeds)
    replayed = replay(profile=profile, data=data, seeds=seeds, ingested_state=ingested["folder_state"])
    evaluated = evaluate(profile=profile, data=data, seeds=seeds)
    policies = policy(profile=profile, data=data, seeds=seeds)
    reported = report(profile=profile, data=data, seeds=seeds)
    return {
        "ingest": ingested,
        "retarget": retargeted,
        "teachers": taught,
        "student": distilled,
        "replay": replayed,
        "evaluate": evaluated,
        "policy": policies,
        "report": reported,
    }


def _by_scoring(rows: list[dict]) -> dict[tuple[str, str], list[dict]]:
    """F1 rows by (reference, source): tactile fidelity first, as in the paper."""
    grouped: dict[tuple[str, str], list[dict]] = {}
    for row in sorted(rows, key=lambda r: (r["reference_source"] != Source.REAL, r["source"], r["method"])):
        grouped.setdefault((row["reference_source"], row["source"]), []).append(row)
    return grouped


def _compared(row: dict) -> str:
    """One method's F1 with its interval and, where paired, the difference the compared-with method makes."""
    text = f"{row['method']} F1 {as_text(row['estimate'], '.3f')} "
    text += f"[{as_text(row['ci_low'], '.3f')}, {as_text(row['ci_high'], '.3f')}]"
    if row["versus"] is not None and row["n_paired"]:
        text += f" ({row['versus']} - it: {as_text(row['difference'], '+.3f')} "
        text += f"[{as_text(row['difference_ci_low'], '+.3f')}, {as_text(row['difference_ci_high'], '+.3f')}], "
        text += f"Holm p {as_text(row['p_holm'], '.2g')}, n {row['n_paired']})"
    return text


def headline(results: dict) -> list[tuple[str, str]]:
    """(stage, its headline figures) of a ``pipeline`` result, for the command's closing table: the
    counts and the figures each stage already returns, a line per stage (per method for the
    teachers, per variant for the student, per task x method for the policies). A stage that
    returned nothing has no line."""
    lines: list[tuple[str, str]] = []
    if ingested := results.get("ingest"):
        counts = (ingested["ingested"], ingested["unchanged"], ingested["quarantined"])
        lines.append(("ingest", "{} ingested, {} unchanged, {} quarantined".format(*counts)))
    if retargeted := results.get("retarget"):
        figures = f"{retargeted['recordings']} recordings, {retargeted['frames']} frames"
        figures += (
            f" ({retargeted['failed_frames']} failed), fingertip residual {retargeted['residual_mean_mm']:.2f} mm"
        )
        lines.append(("retarget", figures))
    by_method: dict[str, list[dict]] = {}
    for row in results.get("teachers") or []:
        by_method.setdefault(row["method"], []).append(row)
    for method, rows in by_method.items():
        seeds = sorted({r["seed"] for r in rows})
        figures = f"{len({r['task'] for r in rows})} tasks" + (f" x {len(seeds)} seeds" if len(seeds) > 1 else "")
        if rows[0]["origin"] == Origin.TEACHER:
            figures += f", {rows[0]['iterations']} iterations"
        success, f1 = fmean(r["success_rate"] for r in rows), fmean(r["contact_f1"] for r in rows)
        lines.append((f"teachers: {method}", f"{figures}, success {success:.2f}, contact F1 {f1:.3f} (task means)"))
    student = results.get("student") or {}
    heldout: dict[tuple[str, int], list[dict]] = {}
    for row in student.get("heldout", []):
        heldout.setdefault((row["variant"], row["seed"]), []).append(row)
    for trained in student.get("trained", []):
        figures = f"{trained['steps']} updates, val loss {trained['initial_val_loss']:.4f} -> "
        figures += f"{trained['final_val_loss']:.4f}"
        if rows := heldout.get((trained["variant"], trained["seed"])):
            joint, kinematic = (
                fmean(r["joint_error_student"] for r in rows),
                fmean(r["joint_error_kinematic"] for r in rows),
            )
            figures += f", joint error {joint:.4f} rad (kinematic {kinematic:.4f})"
            figures += f", contact F1 {fmean(r['contact_f1'] for r in rows):.3f}"
        lines.append((f"student: {trained['variant']} seed {trained['seed']}", figures))
    if replayed := results.get("replay"):
        figures = f"{replayed['replayed']} replayed on the twin, {replayed['skipped']} skipped"
        figures += f", {replayed['failed']} failed"
        lines.append(("replay", figures))
    evaluated = results.get("evaluate") or {}
    for (reference, source), rows in _by_scoring(evaluated.get("f1_compared") or []).items():
        scope = "tactile fidelity" if reference == Source.REAL else f"{source} vs {reference}"
        lines += [(f"evaluate: {scope}" if k == 0 else "", _compared(r)) for k, r in enumerate(rows)]
    if not evaluated.get("f1_compared") and (f1_by_source := evaluated.get("f1")):
        lines.append(("evaluate", "contact F1 " + ", ".join(f"{k} {v:.3f}" for k, v in f1_by_source.items())))
    if policies := results.get("policy"):
        rows = pd.DataFrame(policies)
        for row in pooled_policy(rows, sorted(set(rows["seed"]))).to_dict("records"):
            figures = f"success {row['successes']}/{row['episodes']} [{row['ci_low']:.2f}, {row['ci_high']:.2f}]"
            figures += f" (seeds {row['seeds']} pooled)" if "," in row["seeds"] else ""
            lines.append((f"policy: {row['task']} x {row['method']}", figures))
    if reported := results.get("report"):
        verdicts = [c["verdict"] for c in reported["claims"]]
        counted = ", ".join(
            f"{verdicts.count(v)} {v}" for v in ("holds", "does not hold", "not resolved") if v in verdicts
        )
        lines.append(("report", f"the paper's claims at this size: {counted or 'none measured'}"))
    return lines
