"""The run's report: what the comparison found, as Markdown and as one self-contained HTML page.

Every figure and claim comes from what the catalog holds (``comparison``, ``policy_eval``,
``user_study``, a few demonstrations' ``contacts``: the caller queries them), so anyone can reproduce
them with ``touch2robot sql``; the learning curves come from the stages' MLflow runs. The paper's
claims are stated from the intervals, never from the point estimates alone:

- a contact claim (``versus`` scores higher F1 / a lower onset error than a method) **holds** when
  the paired interval of the difference lies wholly on the claimed side, **does not hold** when it
  lies wholly on the other, and is **not resolved** when it spans 0;
- a policy claim compares Wilson intervals of the successes pooled over the sweep's seeds: it holds
  when ``versus``'s lies wholly above the method's, does not hold when wholly below, and is not
  resolved when they overlap (no paired episode outcomes are stored, so no paired test is made).

A figure pooled over fewer seeds than the sweep ran says which are missing, in its own cell.

No Prefect imports: the task ``tasks.report.build_report`` gathers the data and calls these.
"""

from __future__ import annotations

import base64
import hashlib
import html
import io
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa

from schemas.tables import ROBOT_REGIONS
from schemas.vocabulary import Source
from touch2robot import lake as lake_io
from touch2robot.metrics import ALL

__all__ = [
    "Claim",
    "ReportData",
    "as_text",
    "claims",
    "pooled_policy",
    "render_html",
    "render_markdown",
    "write_report",
]

SCOPES: dict[str, str] = {
    Source.REAL: "Tactile fidelity: a trajectory's contacts in simulation vs those measured on its replay",
    Source.HUMAN: "Preference alignment: a method's robot contacts vs the human's (the glove)",
}
METRIC_LABELS = {
    "f1": "F1",
    "precision": "precision",
    "recall": "recall",
    "fpr": "false-positive rate",
    "onset_error_ms": "onset error (ms)",
}
# the direction each headline metric's claim takes: higher F1 is better, a lower onset error is
HIGHER_IS_BETTER = {"f1": True, "onset_error_ms": False}


@dataclass(frozen=True)
class ReportData:
    """What a report shows: the catalog's tables, the curves, and where they came from."""

    comparison: pd.DataFrame
    policy: pd.DataFrame  # policy_eval rows, one per task x method x seed
    user_study: pd.DataFrame
    provenance: dict[str, str]
    # contacts rows (source, method, task, reference_id, t_ref, region, contact) of a few demonstrations:
    # the human's and every method's replays of them, drawn side by side
    timelines: pd.DataFrame = field(default_factory=pd.DataFrame)
    # learning curves (stage, panel, series, step, value): the teachers', the student variants', the policies'
    curves: pd.DataFrame = field(default_factory=pd.DataFrame)
    figures: dict[str, bytes] = field(default_factory=dict)  # name -> PNG, filled by :func:`draw_figures`
    seeds: tuple[int, ...] = (0,)  # the sweep's seeds: a figure without one of them says so


@dataclass(frozen=True)
class Claim:
    """One of the paper's claims against one method, and what the measurement says of it."""

    statement: str
    verdict: str  # holds | does not hold | not resolved | not measured
    evidence: str


def as_text(value: object, spec: str = ".3f") -> str:
    """A figure of the comparison; an undefined one (NULL: 0/0, a test with no non-zero difference) as n/a."""
    if value is None or (isinstance(value, float) and np.isnan(value)):
        return "n/a"
    return format(value, spec)


def _interval(row: Mapping, spec: str = ".3f") -> str:
    text = f"{as_text(row['estimate'], spec)} [{as_text(row['ci_low'], spec)}, {as_text(row['ci_high'], spec)}]"
    return text + _missing(row)


def _missing(row: Mapping) -> str:
    """A cell's note of the sweep seeds it has no results of ('' when it has them all)."""
    missing = row.get("seeds_missing")
    if not missing or (isinstance(missing, float) and np.isnan(missing)):
        return ""
    return f" (seed {missing} missing)" if "," not in str(missing) else f" (seeds {missing} missing)"


def pooled_policy(policy: pd.DataFrame, seeds: Iterable[int]) -> pd.DataFrame:
    """``policy_eval`` rows pooled over the sweep's seeds per task x method: successes and episodes summed,
    the Wilson interval of the pooled rate, the seeds pooled and those of ``seeds`` with no row."""
    from touch2robot.comparison.statistics import wilson_interval

    columns = [
        "task",
        "method",
        "observation",
        "successes",
        "episodes",
        "success_rate",
        "ci_low",
        "ci_high",
        "train_steps",
    ]
    if policy.empty:
        return pd.DataFrame(columns=[*columns, "seeds", "seeds_missing"])
    swept = set(seeds)
    rows = []
    for (task, method), cell in policy.groupby(["task", "method"], sort=True):
        successes, episodes = int(cell["successes"].sum()), int(cell["episodes"].sum())
        low, high = wilson_interval(successes, episodes)
        have = {int(s) for s in cell["seed"].fillna(0)} if "seed" in cell.columns else {0}
        rows.append(
            {
                "task": task,
                "method": method,
                "observation": ", ".join(sorted(set(cell["observation"]))),
                "successes": successes,
                "episodes": episodes,
                "success_rate": successes / episodes if episodes else float("nan"),
                "ci_low": low,
                "ci_high": high,
                "train_steps": int(cell["train_steps"].max()),
                "seeds": ",".join(map(str, sorted(have))),
                "seeds_missing": ",".join(map(str, sorted(swept - have))),
            }
        )
    return pd.DataFrame(rows)


def _label(row: Mapping) -> str:
    """A comparison row's method, with its student ablation where it is one."""
    return f"{row['method']} ({row['variant']})" if row.get("variant") else str(row["method"])


def _scope_name(reference: str, source: str) -> str:
    if reference == Source.REAL:
        return "tactile fidelity"
    return f"preference alignment, {source} contacts"


def claims(comparison: pd.DataFrame, policy: pd.DataFrame, versus: str) -> list[Claim]:
    """The paper's claims at this run's size: per scored source and method compared with ``versus``, its
    F1 and onset error over all tasks; per task and method, its policy's success rate (``policy``: pooled
    over the seeds, :func:`pooled_policy`)."""
    found: list[Claim] = []
    rows = comparison[(comparison["task"] == ALL) & comparison["metric"].isin(list(HIGHER_IS_BETTER))]
    rows = rows[rows["versus"].notna()]
    ordered = sorted(rows.to_dict("records"), key=lambda r: (r["reference_source"] != Source.REAL, r["source"]))
    for row in ordered:  # tactile fidelity first, as in the paper
        higher = HIGHER_IS_BETTER[row["metric"]]
        scope = _scope_name(row["reference_source"], row["source"])
        better = "higher" if higher else "lower"
        against, label = row["versus"], _label(row)
        if row["variant"]:
            against, label = f"{against}'s full student", f"its {row['variant']} ablation"
        statement = f"{against} has a {better} {METRIC_LABELS[row['metric']]} than {label} ({scope})"
        low, high = row["difference_ci_low"], row["difference_ci_high"]
        spec = "+.3f" if row["metric"] == "f1" else "+.0f"
        evidence = (
            f"{row['versus']} - {_label(row)}: {as_text(row['difference'], spec)} [{as_text(low, spec)}, "
            f"{as_text(high, spec)}], "
            f"Holm p {as_text(row['p_holm'], '.2g')}, {row['n_paired']} paired demonstrations{_missing(row)}"
        )
        if low is None or high is None or np.isnan(low) or np.isnan(high):
            verdict = "not measured"
        elif (low > 0) if higher else (high < 0):
            verdict = "holds"
        elif (high < 0) if higher else (low > 0):
            verdict = "does not hold"
        else:
            verdict = "not resolved"
        found.append(Claim(statement, verdict, evidence))
    by_cell = {(r["task"], r["method"]): r for r in policy.to_dict("records")}
    for (task, method), row in sorted(by_cell.items()):
        if method == versus:
            continue
        statement = f"a policy trained on {versus}'s demonstrations succeeds more often than on {method}'s ({task})"
        ours = by_cell.get((task, versus))
        if ours is None:
            found.append(Claim(statement, "not measured", f"no {versus} policy for {task}"))
            continue
        evidence = (
            f"{versus} {ours['successes']}/{ours['episodes']} [{ours['ci_low']:.2f}, {ours['ci_high']:.2f}]"
            f"{_missing(ours)}, {method} {row['successes']}/{row['episodes']} [{row['ci_low']:.2f}, "
            f"{row['ci_high']:.2f}]{_missing(row)} (Wilson, seeds pooled)"
        )
        if ours["ci_low"] > row["ci_high"]:
            verdict = "holds"
        elif ours["ci_high"] < row["ci_low"]:
            verdict = "does not hold"
        else:
            verdict = "not resolved"
        found.append(Claim(statement, verdict, evidence))
    return found


# --------------------------------------------------------------------------- tables


@dataclass(frozen=True)
class Section:
    """A titled table (header row + rows of text) with an optional figure and note."""

    title: str
    header: list[str]
    rows: list[list[str]]
    figure: str | None = None
    note: str = ""


def _coverage(comparison: pd.DataFrame) -> str:
    """The comparison's interval coverage as text ("95 %")."""
    return f"{100 * float(comparison['confidence'].iloc[0]):g} %" if len(comparison) else "95 %"


def _scores_table(group: pd.DataFrame, scope: str, coverage: str) -> Section:
    """Precision, recall, F1 and FPR over all tasks, per method: the paper's table shape."""
    overall = group[group["task"] == ALL]
    cells = {(_label(r), r["metric"]): r for r in overall.to_dict("records")}
    metrics = ("precision", "recall", "f1", "fpr")
    rows = [
        [method] + [_interval(cells[(method, m)]) if (method, m) in cells else "-" for m in metrics]
        for method in sorted({label for label, _ in cells})
    ]
    header = ["method", *(METRIC_LABELS[m] for m in metrics)]
    return Section(f"{scope}: all tasks", header, rows, note=f"estimate [{coverage} interval over demonstrations]")


def _score_sections(comparison: pd.DataFrame) -> list[Section]:
    sections = []
    coverage = _coverage(comparison)
    scorings = sorted(comparison.groupby(["reference_source", "source"]), key=lambda c: (c[0][0] != Source.REAL, c[0]))
    for (reference, source), group in scorings:
        scope = SCOPES.get(str(reference), f"scored against {reference}")
        if reference != Source.REAL:
            scope += f", {source} contacts"
        sections.append(_scores_table(group, scope, coverage))
        tasks = sorted(set(group["task"]) - {ALL}) + [ALL]
        for metric in ("f1", "onset_error_ms"):
            rows = group[group["metric"] == metric]
            if rows.empty:
                continue
            spec = ".3f" if metric == "f1" else ".0f"
            cells = {(_label(r), r["task"]): r for r in rows.to_dict("records")}
            body = []
            for method in sorted({label for label, _ in cells}):
                line = [method] + [_interval(cells[(method, t)], spec) if (method, t) in cells else "-" for t in tasks]
                overall = cells.get((method, ALL))
                if overall is not None and overall["versus"] is not None and overall["n_paired"]:
                    d_spec = "+.3f" if metric == "f1" else "+.0f"
                    line.append(
                        f"{as_text(overall['difference'], d_spec)} [{as_text(overall['difference_ci_low'], d_spec)}, "
                        f"{as_text(overall['difference_ci_high'], d_spec)}], p_Holm {as_text(overall['p_holm'], '.2g')}"
                    )
                else:
                    line.append("")
                body.append(line)
            versus = next((v for v in rows["versus"] if v is not None), None)
            header = ["method", *["all tasks" if t == ALL else t for t in tasks]]
            header.append(f"{versus} - method (all tasks)" if versus else "paired difference")
            n = int(rows[rows["task"] == ALL]["n_demonstrations"].max())
            sections.append(
                Section(
                    f"{scope}: {METRIC_LABELS[metric]}",
                    header,
                    body,
                    figure=_figure_name(str(reference), str(source), metric),
                    note=f"estimate [{coverage} interval]; up to {n} demonstrations over all tasks",
                )
            )
    return sections


def _policy_section(policy: pd.DataFrame) -> Section:
    """``policy``: pooled over the seeds (:func:`pooled_policy`)."""
    if policy.empty:
        note = "no policy results in the catalog yet: `touch2robot policy` trains and evaluates them"
        return Section("Policy success (closed loop)", [], [], note=note)
    rows = [
        [
            r["task"],
            r["method"],
            r["observation"],
            f"{r['successes']}/{r['episodes']}",
            f"{r['success_rate']:.2f} [{r['ci_low']:.2f}, {r['ci_high']:.2f}]{_missing(r)}",
            r["seeds"],
            str(r["train_steps"]),
        ]
        for r in policy.sort_values(["task", "method"]).to_dict("records")
    ]
    return Section(
        "Policy success (closed loop)",
        ["task", "method", "policy sees", "successes", "rate [95 % Wilson]", "seeds", "updates"],
        rows,
        figure="policy_success",
        note="episodes of every seed's policy pooled; a policy sees 'images' (Table IX: two camera views, the robot "
        "state and the tactile forces) or 'state' (no cameras: the robot state, the tactile forces and the object's "
        "pose)",
    )


def _user_study_section(user_study: pd.DataFrame) -> Section | None:
    if user_study.empty:
        return None
    rows = [
        [
            r["ratings_file"] + (" (SYNTHETIC)" if r["synthetic"] else ""),
            r["question"],
            f"{as_text(r['median_visual_feedback'], '.1f')} / {as_text(r['median_touch2robot'], '.1f')}",
            as_text(r["p"], ".3g"),
            as_text(r["p_holm"], ".3g"),
        ]
        for r in user_study.sort_values(["ratings_file", "question"]).to_dict("records")
    ]
    return Section("User study", ["ratings", "question", "median VF / T2R", "Wilcoxon p", "p_Holm"], rows)


def _timeline_sections(timelines: pd.DataFrame) -> list[Section]:
    if timelines.empty:
        return []
    return [
        Section(
            f"Contact timelines: {task}, demonstration {demonstration}",
            [],
            [],
            figure=_timeline_name(str(task), str(demonstration)),
            note="per robot region: the human's contacts, then each method's measured on its replay (glove clock)",
        )
        for (task, demonstration), _ in timelines.groupby(["task", "reference_id"], sort=True)
    ]


# What each stage's curve shows (the metric its MLflow runs log over training).
CURVE_LABELS = {
    "teachers": "PPO teachers: mean episode reward per iteration",
    "student": "Distilled student: validation loss per update, per variant",
    "policy": "Diffusion Policies: training loss per update",
}


def _curve_sections(curves: pd.DataFrame) -> list[Section]:
    if curves.empty:
        return []
    return [
        Section(f"Learning curves: {CURVE_LABELS.get(str(stage), stage)}", [], [], figure=f"curves_{stage}")
        for stage in sorted(
            set(curves["stage"]), key=lambda st: list(CURVE_LABELS).index(st) if st in CURVE_LABELS else 9
        )
    ]


def _sections(data: ReportData) -> list[Section]:
    found = _score_sections(data.comparison)
    found.append(_policy_section(pooled_policy(data.policy, data.seeds)))
    found += [s for s in (_user_study_section(data.user_study),) if s is not None]
    return found + _timeline_sections(data.timelines) + _curve_sections(data.curves)


# --------------------------------------------------------------------------- figures


def _figure_name(reference: str, source: str, metric: str) -> str:
    return f"{'fidelity' if reference == Source.REAL else f'preference_{source}'}_{metric}"


def _png(fig) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    return buffer.getvalue()


_MISSING = (np.nan, np.nan, np.nan)


def _bars(groups: list[str], series: Mapping[str, list[tuple]], ylabel: str, title: str) -> bytes:
    """Grouped bars (one group per task, one bar per method) with interval whiskers."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(max(5.0, 1.4 * len(groups) + 2), 3.2), layout="constrained")
    ax = fig.subplots()
    width = 0.8 / max(1, len(series))
    x = np.arange(len(groups))
    for k, (name, values) in enumerate(series.items()):
        est = np.array([v[0] for v in values], dtype=float)
        low = np.array([v[1] for v in values], dtype=float)
        high = np.array([v[2] for v in values], dtype=float)
        whiskers = np.nan_to_num(np.vstack([est - low, high - est]), nan=0.0).clip(min=0)
        ax.bar(x + (k - (len(series) - 1) / 2) * width, est, width, yerr=whiskers, capsize=3, label=name)
    ax.set_xticks(x, groups)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, ncols=min(4, len(series)))
    return _png(fig)


def _timeline_name(task: str, demonstration: str) -> str:
    return f"timeline_{task}_{demonstration}"


def _timeline(rows: pd.DataFrame, title: str) -> bytes:
    """One demonstration's contacts, one band per (region, source): the human's on top of each method's."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    human = rows[rows["source"] == Source.HUMAN]
    methods = sorted(set(rows.loc[rows["source"] != Source.HUMAN, "method"]))
    lanes = [("human", human), *((m, rows[(rows["source"] != Source.HUMAN) & (rows["method"] == m)]) for m in methods)]
    fig = Figure(figsize=(10, 0.5 + 0.32 * len(ROBOT_REGIONS) * len(lanes) / 2), layout="constrained")
    ax = fig.subplots()
    height = 1.0 / len(lanes)
    for k, region in enumerate(ROBOT_REGIONS):
        for j, (_, lane) in enumerate(lanes):
            r = lane[lane["region"] == region].sort_values("t_ref")
            low = k + 0.05 + j * 0.9 * height  # the axis is inverted: the human's lane tops each region's band
            ax.fill_between(
                r["t_ref"], low, low + 0.75 * height * r["contact"].astype(float), step="post", color=f"C{j}", lw=0
            )
    ax.set_yticks(np.arange(len(ROBOT_REGIONS)) + 0.5, ROBOT_REGIONS)
    ax.set_ylim(0, len(ROBOT_REGIONS))
    ax.invert_yaxis()
    ax.set_xlabel("time on the glove recording's clock (s)")
    handles = [Patch(color=f"C{j}", label=name) for j, (name, _) in enumerate(lanes)]
    ax.legend(handles=handles, fontsize=8, ncols=len(lanes), loc="upper center", bbox_to_anchor=(0.5, -0.09))
    for k in range(1, len(ROBOT_REGIONS)):
        ax.axhline(k, color="0.85", lw=0.5)
    ax.set_title(title, fontsize=10)
    return _png(fig)


def _curves(rows: pd.DataFrame, title: str) -> bytes:
    """One panel per ``panel`` value (e.g. a task), one line per ``series`` (e.g. a method)."""
    from matplotlib.figure import Figure

    panels = sorted(set(rows["panel"]))
    fig = Figure(figsize=(min(12.0, 3.2 * len(panels) + 1), 3.0), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(panels), sharey=True))
    for ax, panel in zip(axes, panels, strict=True):
        for series, line in rows[rows["panel"] == panel].groupby("series", sort=True):
            line = line.sort_values("step")
            ax.plot(line["step"], line["value"], label=str(series), lw=1.2)
        ax.set_title(str(panel), fontsize=9)
        ax.set_xlabel("step")
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    return _png(fig)


def draw_figures(data: ReportData) -> dict[str, bytes]:
    """Bars with interval whiskers: each scored source's F1 and onset error per task, and policy success."""
    figures: dict[str, bytes] = {}
    coverage = _coverage(data.comparison)
    for (reference, source, metric), rows in data.comparison.groupby(["reference_source", "source", "metric"]):
        if metric not in HIGHER_IS_BETTER:
            continue
        tasks = sorted(set(rows["task"]) - {ALL}) + [ALL]
        cells = {(_label(r), r["task"]): r for r in rows.to_dict("records")}
        series = {
            method: [
                (c["estimate"], c["ci_low"], c["ci_high"]) if (c := cells.get((method, t))) else _MISSING for t in tasks
            ]
            for method in sorted({label for label, _ in cells})
        }
        labels = ["all" if t == ALL else t for t in tasks]
        title = f"{_scope_name(str(reference), str(source))}: {METRIC_LABELS[str(metric)]} ({coverage} interval)"
        figures[_figure_name(str(reference), str(source), str(metric))] = _bars(
            labels, series, METRIC_LABELS[str(metric)], title
        )
    if not data.policy.empty:
        policy = pooled_policy(data.policy, data.seeds)
        tasks = sorted(set(policy["task"]))
        cells = {(r["task"], r["method"]): r for r in policy.to_dict("records")}
        series = {
            method: [
                (c["success_rate"], c["ci_low"], c["ci_high"]) if (c := cells.get((t, method))) else _MISSING
                for t in tasks
            ]
            for method in sorted(set(policy["method"]))
        }
        figures["policy_success"] = _bars(tasks, series, "success rate", "policy success (95 % Wilson interval)")
    if not data.curves.empty:
        for stage, rows in data.curves.groupby("stage", sort=True):
            figures[f"curves_{stage}"] = _curves(rows, CURVE_LABELS.get(str(stage), str(stage)))
    if not data.timelines.empty:
        for (task, demonstration), rows in data.timelines.groupby(["task", "reference_id"], sort=True):
            title = f"{task}, demonstration {demonstration}: contacts per region"
            figures[_timeline_name(str(task), str(demonstration))] = _timeline(rows, title)
    return figures


# --------------------------------------------------------------------------- rendering

_STATISTICS = (
    "Intervals: percentile intervals of a cluster bootstrap over demonstrations (the time-region samples of "
    "one demonstration are not independent), scores pooled over a resample's demonstrations. Paired differences "
    "resample the same demonstrations for both methods; the test is the two-sided Wilcoxon signed-rank test over "
    "the per-demonstration scores, Holm-adjusted over the methods compared on one metric, source and task. Success "
    "rates carry 95 % Wilson intervals. A sweep's seeds pool into each demonstration (its counts summed over "
    "the seeds) and into each policy's episodes; a figure lacking a seed says which. "
    "touch2robot.comparison.statistics documents each choice."
)


def render_markdown(data: ReportData, versus: str) -> str:
    """The report as Markdown (the Prefect artefact and ``report.md``)."""
    lines = [f"# touch2robot report: {data.provenance.get('profile', '')}", ""]
    lines += ["| provenance | |", "|---|---|"] + [f"| {k} | {v} |" for k, v in data.provenance.items()]
    lines += ["", "## What this run found", ""]
    found = claims(data.comparison, pooled_policy(data.policy, data.seeds), versus)
    lines += [f"- **{c.verdict}**: {c.statement}. {c.evidence}" for c in found] or ["- nothing compared yet"]
    for section in _sections(data):
        lines += ["", f"## {section.title}", ""]
        if section.header:
            lines += ["| " + " | ".join(section.header) + " |", "|" + "---|" * len(section.header)]
            lines += ["| " + " | ".join(row) + " |" for row in section.rows]
        if section.note:
            lines += ["", f"_{section.note}_"]
    lines += ["", "## Statistics", "", _STATISTICS, ""]
    return "\n".join(lines)


_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 70em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }
th { background: #f3f3f3; }
.holds { color: #176b2c; } .does-not-hold { color: #a32020; } .not-resolved, .not-measured { color: #7a5b00; }
img { max-width: 100%; }
.note { color: #666; font-size: 0.85em; }
"""


def _html_table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def render_html(data: ReportData, versus: str) -> str:
    """The report as one HTML page with its figures embedded (no file or network it needs)."""
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>touch2robot report: {html.escape(data.provenance.get('profile', ''))}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>touch2robot report: {html.escape(data.provenance.get('profile', ''))}</h1>",
        _html_table(["provenance", ""], data.provenance.items()),
        "<h2>What this run found</h2><ul class='claims'>",
    ]
    found = claims(data.comparison, pooled_policy(data.policy, data.seeds), versus)
    for c in found:
        css = c.verdict.replace(" ", "-")
        parts.append(
            f"<li><b class='{css}'>{html.escape(c.verdict)}</b>: {html.escape(c.statement)}. "
            f"<span class='note'>{html.escape(c.evidence)}</span></li>"
        )
    if not found:
        parts.append("<li>nothing compared yet</li>")
    parts.append("</ul>")
    for section in _sections(data):
        parts.append(f"<section><h2>{html.escape(section.title)}</h2>")
        if section.header:
            parts.append(_html_table(section.header, section.rows))
        if section.note:
            parts.append(f"<p class='note'>{html.escape(section.note)}</p>")
        if section.figure and section.figure in data.figures:
            encoded = base64.b64encode(data.figures[section.figure]).decode()
            parts.append(f"<img alt='{html.escape(section.title)}' src='data:image/png;base64,{encoded}'>")
        parts.append("</section>")
    parts.append(f"<h2>Statistics</h2><p>{html.escape(_STATISTICS)}</p></body></html>")
    return "\n".join(parts)


# --------------------------------------------------------------------------- provenance and writing


def table_digest(*tables: pa.Table | pd.DataFrame) -> str:
    """A digest of the tables a report shows: their schemas and rows, in an order fixed by every column that
    sorts (Arrow's sort and IPC bytes: 30 ms for a smoke run's 90,000 timeline rows, where pandas' string hashing
    took 280)."""
    digest = hashlib.sha256()
    for table in tables:
        if isinstance(table, pd.DataFrame):
            table = pa.Table.from_pandas(table, preserve_index=False)
        keys = [(f.name, "ascending") for f in table.schema if not pa.types.is_nested(f.type)]
        table = (table.sort_by(keys) if len(table) and keys else table).combine_chunks()
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, table.schema) as writer:
            writer.write_table(table)
        digest.update(sink.getvalue())
    return digest.hexdigest()[:16]


def write_report(folder: Path, data: ReportData, versus: str) -> tuple[Path, Path]:
    """``report.md`` and ``report.html`` in ``folder``, each written whole (temp + rename)."""
    folder.mkdir(parents=True, exist_ok=True)
    markdown, page = folder / "report.md", folder / "report.html"
    lake_io.replace_text(render_markdown(data, versus), markdown)
    lake_io.replace_text(render_html(data, versus), page)
    return markdown, page
