"""The ``touch2robot`` command. Every command works on one data folder (``--data``,
``$TOUCH2ROBOT_DATA`` or ``./data``) and needs no server: a flow command runs a Prefect
API of its own that ends with it (app/local_server.py), MLflow a SQLite file,
DuckDB in-process."""

from __future__ import annotations

import atexit
import contextlib
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from app.sql_view import SqlCommand

if TYPE_CHECKING:
    from touch2robot.config import Profile
    from touch2robot.settings import DataLayout

_exit_status: list[int] = []  # the console script's exit status, once ``main`` has it


def _exit_without_teardown() -> None:
    """Registered before any library is imported, so the last exit handler to run (after Prefect's, the API
    server's stop, MLflow's, multiprocessing's): end the console script at once, skipping the interpreter's
    final collections and module teardown (1.6 s of a 13 s cached smoke re-run on 2 cores). Nothing is left to
    write by then: lake, catalog and results files are closed before their rename, logs are shut down here."""
    if not _exit_status:
        return  # the command ran inside another program (a test, a notebook): its exit is its own
    import logging

    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(_exit_status[0])


atexit.register(_exit_without_teardown)

app = typer.Typer(help=__doc__, no_args_is_help=True, pretty_exceptions_show_locals=False)
console = Console()

DataOpt = Annotated[Path | None, typer.Option("--data", "-d", help="data folder (default $TOUCH2ROBOT_DATA or ./data)")]
ProfileOpt = Annotated[str, typer.Option("--profile", "-p", help="smoke | local | paper | path/to/profile.yaml")]
SeedsOpt = Annotated[
    int | None,
    typer.Option(
        "--seeds",
        min=1,
        help="run the stochastic stages for seeds 0..N-1 (default the profile's `seeds:` list)",
        show_default=False,
    ),
]


def _seeds(n: int | None) -> list[int] | None:
    """The sweep of ``--seeds N``: seeds 0 .. N-1 (None: the profile's)."""
    return None if n is None else list(range(n))


def _narrowed(task: list[str] | None, method: list[str] | None, seeds: int | None) -> dict[str, object]:
    """A stage flow's ``tasks``, ``methods`` and ``seeds`` from ``--task``, ``--method`` and ``--seeds``
    (None: the profile's)."""
    return {"tasks": task or None, "methods": method or None, "seeds": _seeds(seeds)}


@dataclass
class _Session:
    command: str = "touch2robot"
    verbose: bool = False


session = _Session()


@app.callback()
def _options(
    ctx: typer.Context,
    verbose: Annotated[
        bool, typer.Option("--verbose", "-v", help="show every log record (libraries' too), not only the run's own")
    ] = False,
) -> None:
    """Global options, before the command."""
    session.command, session.verbose = ctx.invoked_subcommand or session.command, verbose


def _layout(data: Path | None):
    """The data folder, checked before any compute: it must be (or become) a writable folder."""
    from app.environment import configure
    from touch2robot.settings import DataLayout

    layout = DataLayout.from_env(data)
    problem = _unusable_folder(layout.root)
    if problem:
        console.print(f"[red]--data {layout.root}:[/red] {problem}", highlight=False)
        raise typer.Exit(2)
    return configure(layout)


def _unusable_folder(root: Path) -> str | None:
    if root.exists() and not root.is_dir():
        return "not a folder"
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # a file where a parent folder should be, no permission, ...
        return f"cannot create the folder ({e.strerror})"
    if not os.access(root, os.W_OK | os.X_OK):
        return "the folder is not writable"
    return None


def _run_flow[R](entrypoint: str, returns: type[R], **parameters: object) -> R:
    """Call the flow ``module:function`` with ``parameters`` (its result must be a ``returns``)
    against a Prefect API that ends with this command: the user's server when PREFECT_API_URL
    (environment or Prefect profile) names one, else a server of this process on the data folder's database
    (app.local_server: unlike Prefect's temporary server, it cannot outlive a
    killed run). The server starts first and comes up while Prefect and the flow's
    modules are imported. Call after ``_layout``: Prefect reads its settings once, when
    first imported. Every log record goes to <data>/logs/<command>-<time>.log, the terminal
    shows what app.terminal lets through (all of it with --verbose)."""
    import atexit
    import importlib

    from app.local_server import PrefectApi, running_ui_api, stop_on_termination
    from tasks import logs
    from touch2robot.settings import DataLayout

    module, function = entrypoint.split(":")
    layout = DataLayout.from_env()  # the folder ``_layout`` configured
    root = layout.root
    log_file = root / "logs" / f"{session.command}-{time.strftime('%Y%m%d-%H%M%S')}.log"
    log_file.parent.mkdir(parents=True, exist_ok=True)
    console.print(f"[dim]log: {log_file}[/]", highlight=False)
    with (
        _command_environ(logs.LOG_FILE_ENV, logs.VERBOSE_ENV),
        _writer_lock(root),
        stop_on_termination(),
    ):
        # for this process and the task runners' workers: MLflow's records go through logging like
        # every library's instead of MLflow's own handler on stderr
        os.environ.update({logs.LOG_FILE_ENV: str(log_file), logs.VERBOSE_ENV: "1" if session.verbose else "0"})
        os.environ.setdefault("MLFLOW_CONFIGURE_LOGGING", "false")
        # a running `touch2robot ui --start` of this folder serves its database already: its API
        # answers at once, where a server of this command takes seconds to start and warm up
        ui_api = None if os.environ.get("PREFECT_API_URL") else running_ui_api(layout.prefect_home)
        api = None if os.environ.get("PREFECT_API_URL") or ui_api else PrefectApi(dict(os.environ)).start()
        from prefect.settings import (
            PREFECT_API_URL,
            PREFECT_FLOWS_HEARTBEAT_FREQUENCY,
            get_current_settings,
            temporary_settings,
        )

        from app.terminal import TerminalHandler

        settings = get_current_settings()
        if settings.api.url:  # the user's Prefect profile names a server
            if api is not None:
                api.stop()
            api = ui_api = None
        terminal = TerminalHandler(console, verbose=session.verbose, own_api=api is not None)
        logs.configure(str(log_file), terminal)
        logs.show_worker_logs_with(None if session.verbose else terminal)
        flow = getattr(importlib.import_module(module), function)
        with terminal:
            if api is None and ui_api is None:
                result = flow(**parameters)
            else:
                if api is not None:
                    # stopped at exit, after Prefect's log and event workers have sent what they hold
                    # (they drain at thread shutdown, before atexit), as Prefect stops its own server
                    atexit.register(api.stop)
                    _import_what_a_flow_run_imports()
                    url = api.wait_ready(settings.server.ephemeral.startup_timeout_seconds)
                else:
                    assert ui_api is not None  # the branch's condition
                    url = ui_api
                    console.print(f"[dim]Prefect API: the server of `touch2robot ui`, {url}[/]", highlight=False)
                os.environ["PREFECT_API_URL"] = url  # for processes the flow starts (task runners)
                # and for threads without the flow's context (a process pool's result and log
                # forwarding): they read the global settings, made at import, before this URL existed
                from prefect.context import refresh_global_settings_context

                refresh_global_settings_context()
                _one_tls_context_for_api_clients()
                # no heartbeats: they tell a lasting server which runs crashed, and these servers end
                # with a command; each flow run's end waits up to a second for its heartbeat thread
                with temporary_settings({PREFECT_API_URL: url, PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
                    result = flow(**parameters)
    if not isinstance(result, returns):
        raise TypeError(f"flow {entrypoint} returned a {type(result).__name__}, not a {returns.__name__}")
    return result


def _import_what_a_flow_run_imports() -> None:
    """Prefect's flow and task engines and fastapi's encoder (a flow run's parameters go through it: 0.43 s to
    import), which the first flow run imports: imported while this command's API server starts. Its start takes
    longer than the flows' import (4 of its 6 s are left then on 2 cores), so the flow run finds them loaded."""
    import fastapi.encoders  # noqa: F401
    import prefect.flow_engine
    import prefect.task_engine
    import prefect.utilities.visualization  # noqa: F401


def _one_tls_context_for_api_clients() -> None:
    """Prefect's API clients share one TLS context per certificate bundle. Each client builds its own from
    certifi's bundle, even for an http:// API like this command's server: 45 ms of CPU a client, 16 clients (a
    subflow's start makes one) and 0.77 s of a cached smoke re-run. Called only where the API is this command's
    server or the UI's, both plain http on 127.0.0.1, so the context is never used for a connection."""
    import functools
    import ssl
    import types

    import prefect.client.orchestration as orchestration

    if isinstance(vars(orchestration)["ssl"], types.SimpleNamespace):
        return
    shared = types.SimpleNamespace(**vars(ssl))
    shared.create_default_context = functools.cache(ssl.create_default_context)
    # the module's own ``ssl`` name (not one it exports): every other user of ssl keeps the real one
    setattr(orchestration, "ssl", shared)  # noqa: B010


@contextmanager
def _command_environ(*names: str) -> Iterator[None]:
    """The log file a command names for the processes its flow starts is put back when it ends: a later
    command of the same process (a notebook, a test) must not send its workers' logs into this one's
    folder. (Its Prefect API stays: the server lives until the process exits and later commands use it.)"""
    saved = {name: os.environ.get(name) for name in names}
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@contextmanager
def _writer_lock(root: Path) -> Iterator[None]:
    """One writing command per data folder: a second one would resume from the first's half-written
    checkpoints (touch2robot.folder_lock)."""
    from touch2robot.folder_lock import DataFolderBusy, hold_data_folder

    try:
        with hold_data_folder(root, f"touch2robot {session.command}"):
            yield
    except DataFolderBusy as e:  # raised only on entry: nobody else raises it
        console.print(f"[red]busy:[/red] {e}", highlight=False)
        raise typer.Exit(1) from None


def _check_profile(profile: str) -> Profile:
    """The profile, loaded before any work; a bad one ends the command (exit 2) saying why."""
    from touch2robot.config import ProfileError, load_profile

    try:
        return load_profile(profile)
    except ProfileError as e:
        console.print(f"[red]bad profile:[/red] {e}")
        raise typer.Exit(2) from None


@app.command()
def synth(profile: ProfileOpt = "smoke", data: DataOpt = None) -> None:
    """Write the simulated demonstrator's glove sessions (MCAP) into <data>/recordings, ground
    truth into <data>/groundtruth. Robot replays come from `touch2robot replay`."""
    from schemas.rig import DEFAULT_RIG
    from touch2robot.config import load_profile
    from touch2robot.ingest.rigs import write_rig
    from touch2robot.synth.generate import plan, write_recording
    from touch2robot.synth.ratings import write_ratings_csv

    _check_profile(profile)
    layout = _layout(data)
    config = load_profile(profile).synth
    jobs = plan(config)
    write_rig(DEFAULT_RIG, layout.recordings)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as bar:
        task = bar.add_task("synthesising", total=len(jobs))
        for job in jobs:
            bar.update(task, description=job.stem)
            write_recording(config, job, layout.recordings, layout.groundtruth)
            bar.advance(task)
    write_ratings_csv(layout.synthetic_ratings, seed=config.seed)
    console.print(f"{len(jobs)} recordings in {layout.recordings}")


@app.command()
def ingest(
    profile: ProfileOpt = "smoke",
    data: DataOpt = None,
    folder: Annotated[
        Path | None,
        typer.Option(
            help="folder of recordings: MCAP files and rosbag2 folders (default <data>/recordings)",
            exists=True,
            file_okay=False,
        ),
    ] = None,
    session: Annotated[
        list[str] | None,
        typer.Option(
            help="a session field (kind, task, subject, method, reference_recording, calibration_recording, rig, "
            "...) as FIELD=VALUE, for recordings whose MCAP record, rosbag2 custom_data and sidecar "
            "<recording>.session.yaml do not give it; repeat for several",
        ),
    ] = None,
    rig: Annotated[
        list[Path] | None,
        typer.Option(
            help="a rig file (topics, taxel regions, joint names, sensor channels; see simulated.rig.yaml in "
            "<data>/recordings) besides the *.rig.yaml files in the recordings folder; repeat for several",
            exists=True,
            dir_okay=False,
        ),
    ] = None,
) -> None:
    """Ingest recordings (MCAP files, rosbag2 folders of MCAP or sqlite3 storage) into the Parquet lake and
    DuckDB catalog (Prefect flow `ingest`, cached per file content): bad files are quarantined with a reason.
    Each recording is read with the rig its session field `rig` names (default: the simulated rig)."""
    fields = _session_fields(session or [])
    _check_profile(profile)
    layout = _layout(data)
    rig_files = [str(p.resolve()) for p in rig or []]
    _check_rigs(folder or layout.recordings, rig_files, fields)
    result = _run_flow(
        "flows.ingest:ingest",
        dict,
        profile=profile,
        data=str(layout.root),
        folder=str(folder.resolve()) if folder else None,
        session=fields,
        rig_files=rig_files,
    )
    _closing(layout, f"ingest ({profile})", {"ingest": result})


def _check_rigs(folder: Path, rig_files: list[str], session: dict[str, str]) -> None:
    """Every rig, and its topics against the recordings that name it, checked before any file is ingested;
    a bad one ends the command (exit 2) naming the file and field."""
    from touch2robot.ingest.rigs import RigError, checked_rigs

    try:
        checked_rigs(folder, rig_files, session)
    except RigError as e:
        console.print(f"[red]bad rig:[/red] {e}")
        raise typer.Exit(2) from None


def _session_fields(pairs: list[str]) -> dict[str, str]:
    """``--session FIELD=VALUE`` options as fields, checked before anything else runs."""
    from touch2robot.ingest.sources import SourceError, checked_fields

    fields: dict[str, str] = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name.strip():
            raise typer.BadParameter(f"{pair!r} is not FIELD=VALUE", param_hint="--session")
        fields[name.strip()] = value.strip()
    try:
        return checked_fields(fields, "--session")
    except SourceError as e:
        raise typer.BadParameter(str(e), param_hint="--session") from None


@app.command()
def retarget(profile: ProfileOpt = "smoke", data: DataOpt = None) -> None:
    """Kinematic retargeting of every ingested glove recording to LEAP joints (flow `retarget`)."""
    _check_profile(profile)
    layout = _layout(data)
    result = _run_flow("flows.retarget:retarget", dict, profile=profile, data=str(layout.root))
    _closing(layout, f"retarget ({profile})", {"retarget": result})


@app.command()
def teachers(
    profile: ProfileOpt = "smoke",
    data: DataOpt = None,
    task: Annotated[
        list[str] | None, typer.Option(help="task to train (repeatable; default the profile's teacher.tasks)")
    ] = None,
    method: Annotated[
        list[str] | None, typer.Option(help="touch2robot | contrack | dexmachina (repeatable; default all)")
    ] = None,
    seeds: SeedsOpt = None,
) -> None:
    """Train PPO teachers per task x method, record their rollouts and the kinematic replays
    (flow `teachers`); a killed training resumes from its last checkpoint."""
    _check_profile(profile)
    layout = _layout(data)
    rows = _run_flow(
        "flows.teachers:teachers",
        list,
        profile=profile,
        data=str(layout.root),
        **_narrowed(task, method, seeds),
    )
    _closing(layout, f"teachers ({profile})", {"teachers": rows})


@app.command()
def student(
    profile: ProfileOpt = "smoke",
    data: DataOpt = None,
    variant: Annotated[
        list[str] | None, typer.Option(help="full or an ablation of student.ablations (repeatable; default all)")
    ] = None,
    seeds: SeedsOpt = None,
) -> None:
    """Distil the unified student retargeter from the touch2robot teachers' rollouts (augmented
    dataset, full model and ablations), then reconstruct the held-out demonstrations (flow
    `student`); a killed training resumes from its last checkpoint."""
    _check_profile(profile)
    layout = _layout(data)
    result = _run_flow(
        "flows.student:student",
        dict,
        profile=profile,
        data=str(layout.root),
        variants=variant or None,
        seeds=_seeds(seeds),
    )
    table = Table(
        "variant", "seed", "task", "joint error (rad)", "kinematic input (rad)", "contact F1", "predicted F1", "success"
    )
    for r in result.get("heldout", []):
        table.add_row(
            r["variant"],
            str(r["seed"]),
            r["task"],
            f"{r['joint_error_student']:.4f}",
            f"{r['joint_error_kinematic']:.4f}",
            f"{r['contact_f1']:.3f}",
            f"{r['predicted_contact_f1']:.3f}",
            f"{r['success_rate']:.2f}",
        )
    console.print(table)


@app.command()
def replay(
    profile: ProfileOpt = "smoke",
    data: DataOpt = None,
    task: Annotated[
        list[str] | None, typer.Option(help="task to replay (repeatable; default the profile's replay.tasks)")
    ] = None,
    method: Annotated[
        list[str] | None,
        typer.Option(help="touch2robot | contrack | dexmachina | dex-retargeting (repeatable; default all)"),
    ] = None,
    seeds: SeedsOpt = None,
) -> None:
    """Execute each method's robot trajectories open loop on the hardware twin (a perturbed MuJoCo rig
    with TwinTac and FSR models), write robot replay MCAPs next to their glove sessions and ingest
    them (flow `replay`); a method with no trajectory for a task is skipped with the reason."""
    _check_profile(profile)
    layout = _layout(data)
    result = _run_flow(
        "flows.replay:replay",
        dict,
        profile=profile,
        data=str(layout.root),
        **_narrowed(task, method, seeds),
    )
    _closing(layout, f"replay ({profile})", {"replay": result})


@app.command()
def evaluate(
    profile: ProfileOpt = "smoke",
    data: DataOpt = None,
    ratings: Annotated[
        Path | None,
        typer.Option(help="user-study ratings CSV or folder (default <data>/recordings/user_study)", exists=True),
    ] = None,
    seeds: SeedsOpt = None,
) -> None:
    """Score every contact source against the human preference (precision/recall/F1/FPR,
    onset error), every replayed trajectory against its replay (tactile fidelity), compare the
    methods (intervals over demonstrations, paired tests) and the user study; tables
    contact_metrics, onset_errors, comparison, user_study."""
    _check_profile(profile)
    layout = _layout(data)
    result = _run_flow(
        "flows.evaluate:evaluate",
        dict,
        profile=profile,
        data=str(layout.root),
        ratings=str(ratings.resolve()) if ratings else None,
        seeds=_seeds(seeds),
    )
    _closing(layout, f"evaluate ({profile})", {"evaluate": result})


@app.command()
def report(profile: ProfileOpt = "smoke", data: DataOpt = None, seeds: SeedsOpt = None) -> None:
    """The run's report from the catalog: report.html (self-contained, figures embedded) and report.md
    under <data>/reports/, the paper's claims stated from the intervals, an artefact and an MLflow run."""
    _check_profile(profile)
    layout = _layout(data)
    result = _run_flow("flows.report:report", dict, profile=profile, data=str(layout.root), seeds=_seeds(seeds))
    _closing(layout, f"report ({profile})", {"report": result})


@app.command()
def policy(
    profile: ProfileOpt = "smoke",
    data: DataOpt = None,
    task: Annotated[
        list[str] | None, typer.Option(help="task (repeatable; default the profile's policy.tasks)")
    ] = None,
    method: Annotated[
        list[str] | None, typer.Option(help="data-collection method (repeatable; default the profile's policy.methods)")
    ] = None,
    seeds: SeedsOpt = None,
) -> None:
    """Robot demonstrations as LeRobot datasets, LeRobot's Diffusion Policy trained on them and
    its closed-loop success, per task x method with rollouts in the lake (table policy_eval)."""
    _check_profile(profile)
    layout = _layout(data)
    rows = _run_flow(
        "flows.policy:policy",
        list,
        profile=profile,
        data=str(layout.root),
        **_narrowed(task, method, seeds),
    )
    table = Table(
        "task",
        "method",
        "seed",
        "origin",
        "sees",
        "success",
        "95% CI",
        "progress",
        "demonstrations replayed",
        "open-loop error (rad / mm)",
        "holding still",
    )
    for r in rows:
        table.add_row(
            r["task"],
            r["method"],
            str(r["seed"]),
            r["origin"],
            r["observation"],
            f"{r['successes']}/{r['episodes']}",
            f"[{r['ci_low']:.2f}, {r['ci_high']:.2f}]",
            f"{r['mean_progress']:.2f}",
            f"{r['replay_successes']}/{r['episodes']}",
            f"{r['fit_joint_err_rad']:.3f} / {r['fit_wrist_err_mm']:.1f}",
            f"{r['hold_joint_err_rad']:.3f} / {r['hold_wrist_err_mm']:.1f}",
        )
    console.print(table)


@app.command()
def run(
    profile: ProfileOpt = "smoke",
    data: DataOpt = None,
    synthesize: Annotated[
        bool, typer.Option("--synth/--no-synth", help="generate demonstrator recordings first")
    ] = True,
    seeds: SeedsOpt = None,
) -> None:
    """Run every stage that exists, as one Prefect flow (`pipeline`), on a profile."""
    _check_profile(profile)
    layout = _layout(data)
    result = _run_flow(
        "flows.pipeline:pipeline",
        dict,
        profile=profile,
        data=str(layout.root),
        synthesize=synthesize,
        seeds=_seeds(seeds),
    )
    _closing(layout, f"pipeline ({profile})", result)


def _closing(layout: DataLayout, title: str, results: dict) -> None:
    """The headline figures of what ran (``flows.pipeline.headline``) and where to look next."""
    from flows.pipeline import headline  # imported by now: Prefect after _layout's settings

    table = Table("stage", "headline figures", title=title, title_justify="left")
    for stage, figures in headline(results):
        table.add_row(stage, figures)
    console.print(table)
    if reported := results.get("report"):
        console.print(f"report: {reported['html']}", highlight=False, soft_wrap=True)
    console.print(
        f"next:  touch2robot ui --start --data {layout.root}    the MLflow and Prefect UIs of these runs\n"
        f'       touch2robot sql "SELECT * FROM policy_eval" --data {layout.root}    the tables\n'
        f"       {layout.root}    the data folder (lake/, checkpoints/, policies/, logs/)",
        highlight=False,
        soft_wrap=True,
    )


@app.command(cls=SqlCommand)
def sql(
    query: Annotated[
        str | None,
        typer.Argument(help='read-only SQL, e.g. "SELECT region, avg(contact::INT) FROM contacts GROUP BY ALL"'),
    ] = None,
    data: DataOpt = None,
    csv: Annotated[bool, typer.Option("--csv", help="print CSV (full precision) instead of a table")] = False,
    limit: Annotated[int, typer.Option(help="rows to print in table mode")] = 50,
    vertical: Annotated[
        bool,
        typer.Option("--vertical", "-x", help="one field per line (default when a row is wider than the terminal)"),
    ] = False,
    timeout: Annotated[float, typer.Option(help="seconds before the query is interrupted (0: no limit)")] = 60.0,
    tables: Annotated[bool, typer.Option("--tables", help="list every table: description and row count")] = False,
    describe: Annotated[
        str | None, typer.Option("--describe", metavar="TABLE", help="a table's columns, types, descriptions")
    ] = None,
) -> None:
    """Query the catalog with SQL, read-only: SELECT (DESCRIBE, SUMMARIZE, ...) and EXPLAIN of
    a SELECT; no file outside the lake can be read, none written. Column descriptions are also
    in duckdb_columns() for any DuckDB client."""
    import duckdb

    from app import sql_view
    from touch2robot import catalog
    from touch2robot.settings import DataLayout

    if sum((query is not None, tables, describe is not None)) != 1:
        console.print("[red]give one of: a QUERY, --tables or --describe TABLE[/red]")
        raise typer.Exit(2)
    layout = DataLayout.from_env(data)
    try:
        if tables:
            sql_view.print_tables(console, catalog.tables(layout))
            return
        if describe is not None:
            sql_view.print_description(console, catalog.describe(layout, describe))
            return
        assert query is not None  # the one thing asked for, checked above
        result = catalog.query(layout, query, timeout_s=timeout or None)
    except catalog.QueryTimeout as e:
        console.print(f"[red]QueryTimeout:[/red] {e} (--timeout sets it)")
        raise typer.Exit(1) from None
    except (ValueError, FileNotFoundError, duckdb.Error) as e:  # QueryRefused is a ValueError
        console.print(f"[red]{type(e).__name__}:[/red] {e}")
        raise typer.Exit(1) from None
    if csv:
        sql_view.write_csv(result)
    else:
        sql_view.print_result(console, result, limit, vertical)


@app.command()
def ui(
    data: DataOpt = None,
    port: Annotated[int, typer.Option(help="port for the MLflow UI")] = 5000,
    prefect_port: Annotated[int, typer.Option(help="port for the Prefect UI")] = 4200,
    start: Annotated[bool, typer.Option("--start", help="start the UIs (else print the commands)")] = False,
) -> None:
    """The MLflow UI on the data folder's tracking store and the Prefect UI on its Prefect
    database (the runs of every command on that folder). With --start both run on
    127.0.0.1 until Ctrl-C or SIGTERM, which stops them and every process they started."""
    import signal

    layout = _layout(data)
    from app.local_server import UI_API_RECORD, StopRequest, answers, record_ui_api, spawn_owned, stop_group
    from tasks.tracking import local_uri, relocate_store, tracking_uri

    # name: (command, health URL, UI URL); a server the user points at is theirs to run
    servers: dict[str, tuple[list[str], str, str]] = {}
    uri = tracking_uri(layout)
    if uri == local_uri(layout):
        relocate_store(layout)  # a copied data folder's runs show their artefacts from this copy
        # one web worker and no GenAI job runner (by default 4 workers and 8 job processes)
        command = [
            sys.executable,
            "-m",
            "mlflow",
            "ui",
            "--backend-store-uri",
            uri,
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--workers",
            "1",
        ]
        servers["MLflow"] = (command, f"http://127.0.0.1:{port}/health", f"http://127.0.0.1:{port}")
    else:
        console.print(f"MLflow UI:  {uri} (MLFLOW_TRACKING_URI)")
    if os.environ.get("PREFECT_API_URL"):
        console.print(f"Prefect UI: the server of PREFECT_API_URL={os.environ['PREFECT_API_URL']}")
    else:
        command = [
            sys.executable,
            "-m",
            "prefect",
            "server",
            "start",
            "--host",
            "127.0.0.1",
            "--port",
            str(prefect_port),
        ]
        servers["Prefect"] = (
            command,
            f"http://127.0.0.1:{prefect_port}/api/health",
            f"http://127.0.0.1:{prefect_port}",
        )
    env = {
        **os.environ,
        "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": os.environ.get("MLFLOW_SERVER_ENABLE_JOB_EXECUTION", "false"),
    }
    if not start:
        shell_env = {
            "MLflow": "MLFLOW_SERVER_ENABLE_JOB_EXECUTION=false",
            "Prefect": f"PREFECT_HOME={env['PREFECT_HOME']}",
        }
        for name, (command, _, _) in servers.items():
            console.print(f"{name} UI: {shell_env[name]} uv run {command[2]} " + " ".join(command[3:]), soft_wrap=True)
        console.print("(or `touch2robot ui --start` runs both)")
        return
    if not servers:
        return
    with StopRequest() as stop:
        running = {name: spawn_owned(command, env) for name, (command, _, _) in servers.items()}
        try:
            announced: set[str] = set()
            while stop.wait(0.5) is None and all(proc.poll() is None for proc in running.values()):
                for name in running.keys() - announced:
                    if answers(servers[name][1]):
                        console.print(f"{name} UI on {servers[name][2]}")
                        announced.add(name)
                        if name == "Prefect":  # the folder's flow commands use it (app.local_server)
                            record_ui_api(layout.prefect_home, f"{servers[name][2]}/api", running[name].pid)
                        if announced == running.keys():
                            console.print("Ctrl-C stops them")
            if stop.signum is None:
                failed = next(name for name, proc in running.items() if proc.poll() is not None)
                console.print(f"[red]the {failed} server exited with status {running[failed].returncode}[/red]")
                raise typer.Exit(1)
            console.print("stopping")
        finally:
            (layout.prefect_home / UI_API_RECORD).unlink(missing_ok=True)
            for proc in running.values():
                stop_group(proc)
    if stop.signum != signal.SIGINT:  # a SIGTERM or SIGHUP ends the command as that signal would
        raise typer.Exit(128 + stop.signum)


@app.command()
def deploy(
    pool: Annotated[
        str,
        typer.Option(
            "--pool", help="work pool (created if missing): touch2robot-local, touch2robot-docker or your own"
        ),
    ] = "touch2robot-local",
    flow: Annotated[list[str] | None, typer.Option("--flow", help="only this flow's deployment (repeatable)")] = None,
) -> None:
    """Register the deployments of prefect.yaml on a work pool of the Prefect server named by
    PREFECT_API_URL (see infra/README.md)."""
    from app.deploy import deploy_all

    try:
        deployed = deploy_all(pool, flows=flow)
    except (RuntimeError, ValueError) as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    for name, deployment_id in deployed.items():
        console.print(f"{name}  {deployment_id}")
    console.print(f"start a worker: uv run prefect worker start --pool {pool}")


@app.command()
def view(
    recording: Annotated[
        str | None, typer.Argument(help="glove session: recording id or file name (default: list them)")
    ] = None,
    data: DataOpt = None,
    trajectory: Annotated[
        str | None, typer.Option(help="robot trajectory to show first: a rollout id or a twin replay's recording id")
    ] = None,
    host: Annotated[str, typer.Option(help="address to serve on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port to serve on")] = 8080,
    live: Annotated[
        Path | None, typer.Option(help="follow this glove session MCAP while it is written (live feedback)")
    ] = None,
    realtime: Annotated[
        bool, typer.Option("--realtime", help="live: re-record RECORDING at real-time speed and follow it")
    ] = False,
    time_budget: Annotated[float, typer.Option(help="user study: seconds per condition")] = 60.0,
    ratings: Annotated[
        Path | None, typer.Option(help="user study: the ratings CSV (default recordings/user_study/ratings_study.csv)")
    ] = None,
    export: Annotated[
        Path | None, typer.Option(help="write the demonstration and the trajectory as a Rerun .rrd file and exit")
    ] = None,
) -> None:
    """The contact feedback view in a browser: the human's keypoints and glove contacts beside the LEAP Hand
    posed by a robot trajectory with its tactile regions, a timeline, per-region contact timelines, the
    Visual Feedback / Touch2Robot condition switch and the user-study questionnaire (saved where `evaluate`
    reads ratings). `--live FILE` follows a recording being written; `--realtime` re-records RECORDING
    at real-time speed and follows it, printing the latency from each message's stamp to the page."""
    import threading

    layout = _layout(data)
    from app.view import FeedbackView, PortInUse
    from touch2robot.view.demonstration import ViewError, glove_sessions, load_demonstration, load_trajectory
    from touch2robot.view.follow import LiveSession, live_retargeter, replay_in_real_time

    try:
        if recording is None:
            sessions = glove_sessions(layout)
            for rid, file_name, task in sessions:
                console.print(f"{rid}  {file_name}  ({task})")
            console.print(f"{len(sessions)} glove session(s): `touch2robot view ID` opens one")
            return
        demo = load_demonstration(layout, recording)
        if export is not None:
            from touch2robot.view.export import write_rrd

            choice = next((c for c in demo.trajectories if c.key == trajectory), None) if trajectory else None
            choice = choice or next(iter(demo.trajectories), None)
            robot = load_trajectory(layout, choice) if choice is not None else None
            console.print(f"wrote {write_rrd(demo, robot, export)}")
            return
    except ViewError as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    stop = threading.Event()
    follow = live
    if realtime:
        import tempfile

        source = layout.recordings / demo.file_name
        follow = Path(tempfile.mkdtemp(prefix="touch2robot-live-")) / f"live_{demo.file_name}"
        threading.Thread(target=replay_in_real_time, args=(source, follow, stop), daemon=True).start()
        while not follow.exists():
            time.sleep(0.01)
    if follow is not None and not follow.is_file():
        console.print(f"[red]--live {follow}: no such file[/red]")
        raise typer.Exit(2)
    session = LiveSession(follow, retarget=live_retargeter()) if follow is not None else None
    try:
        viewer = FeedbackView(layout, demo, host, port, trajectory, session, time_budget, ratings)
    except (PortInUse, ViewError) as e:
        console.print(f"[red]{e}[/red]")
        raise typer.Exit(2) from None
    console.print(f"view of {demo.file_name} on http://{host}:{port} (Ctrl-C stops it)")
    if session is not None:
        import numpy as np

        def report() -> None:
            while not stop.wait(5.0):
                if viewer.latency_ms:
                    lat = np.asarray(viewer.latency_ms)
                    console.print(
                        f"live: {len(lat)} updates, latency message stamp -> page p50 {np.median(lat):.1f} ms, "
                        f"p95 {np.percentile(lat, 95):.1f} ms"
                    )

        threading.Thread(target=report, daemon=True).start()
    try:
        viewer.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()


sim_app = typer.Typer(help="The MuJoCo scenes of the four tasks.", no_args_is_help=True)
app.add_typer(sim_app, name="sim")


@sim_app.command("render")
def sim_render(
    out: Annotated[Path, typer.Option(help="folder for the PNGs")] = Path("data/reports/scenes"),
    size: Annotated[int, typer.Option(help="image width and height in pixels")] = 224,
) -> None:
    """Render every task scene at its reset state from both cameras (headless: MUJOCO_GL=egl)."""
    from touch2robot.sim.render import render_scenes

    for path in render_scenes(out, size, size):
        console.print(str(path))


@sim_app.command("check")
def sim_check(
    profile: ProfileOpt = "local",
    data: DataOpt = None,
    task: Annotated[
        list[str] | None, typer.Option(help="task to check (repeatable; default the profile's teacher.tasks)")
    ] = None,
    each: Annotated[
        bool, typer.Option("--each", "--verbose", "-v", help="also print every demonstration's replay")
    ] = False,
) -> None:
    """Each task's reference success: the kinematic replay (Dex Retargeting) of every retargeted
    demonstration in MuJoCo, as the teachers start from it. Exit 1 when a task is below the target
    share of successful demonstrations, 2 when there is nothing to replay. Reads the lake only."""
    import math

    from touch2robot import scenes
    from touch2robot.settings import DataLayout

    teacher = _check_profile(profile).teacher
    unknown = sorted(set(task or ()) - set(scenes.REGISTRY))
    if unknown:
        console.print(f"[red]unknown task {', '.join(unknown)}[/red] (tasks: {', '.join(scenes.REGISTRY)})")
        raise typer.Exit(2)
    tasks = tuple(task or teacher.tasks)
    layout = DataLayout.from_env(data)
    if not layout.lake.is_dir():
        console.print(
            f"[red]no lake in {layout.root}[/red]: run touch2robot ingest and touch2robot retarget "
            f"--data {layout.root}",
            highlight=False,
            soft_wrap=True,
        )
        raise typer.Exit(2)

    from touch2robot.teachers.check import REFERENCE_TARGET, check_references, summarize

    with console.status(f"replaying the demonstrations of {', '.join(tasks)}"):
        rows = check_references(layout.lake, tasks, teacher.sim, teacher)
    summaries = summarize(rows, tasks)
    if each or session.verbose:
        demos = Table(title="kinematic replay of each demonstration", title_justify="left")
        demos.add_column("task")
        demos.add_column("recording", no_wrap=True)
        # tracking lost: the object left its reference by more than the teachers' thresholds;
        # the largest position (drawer: opening) and orientation errors over the replay
        for header in ("subject", "success", "progress", "lost (s)", "err (cm)", "rot (deg)"):
            demos.add_column(header, justify="left" if header in ("subject", "success") else "right")
        for r in rows:
            demos.add_row(
                r.task,
                r.recording_id,
                r.subject,
                "yes" if r.success else "[red]no[/red]",
                f"{r.progress:.2f}",
                "-" if r.lost_at_s is None else f"{r.lost_at_s:.2f}",
                f"{100 * r.max_pos_error_m:.1f}",
                f"{math.degrees(r.max_rot_error_rad):.0f}",
            )
        console.print(demos)
    for r in rows:
        if r.physics_error:
            console.print(f"[red]lost physics[/red] in {r.recording_id}: {r.physics_error}", highlight=False)
    table = Table(
        "task",
        "demonstrations",
        "successes",
        "rate",
        "result",
        title=f"reference success ({profile}), target {REFERENCE_TARGET:.2f}",
        title_justify="left",
    )
    for s in summaries:
        if s.rate is None:
            table.add_row(s.task, "0", "-", "-", "[yellow]no retargeted demonstrations[/yellow]")
        else:
            result = "pass" if s.passed else "[red]FAIL[/red]"
            table.add_row(s.task, str(s.demonstrations), str(s.successes), f"{s.rate:.2f}", result)
    console.print(table)
    missing = [s.task for s in summaries if s.rate is None]
    if missing:
        console.print(
            f"[red]no retargeted demonstrations of {', '.join(missing)}[/red] in {layout.lake}: "
            f"run touch2robot retarget --data {layout.root}",
            highlight=False,
            soft_wrap=True,
        )
        raise typer.Exit(2)
    if not all(s.passed for s in summaries):
        raise typer.Exit(1)


def main() -> None:
    """The console script ``touch2robot``: the command, then ``_exit_without_teardown``."""
    try:
        app()
    except SystemExit as stop:
        code = stop.code
        _exit_status.append(code if isinstance(code, int) else 0 if code is None else 1)
        raise
    except KeyboardInterrupt:
        _exit_status.append(130)
        raise
    except BaseException:
        _exit_status.append(1)
        raise


if __name__ == "__main__":
    main()
