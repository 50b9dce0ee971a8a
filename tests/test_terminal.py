"""The terminal of a flow command: at default verbosity a library's chatter stays in the run's log
file and off the terminal, --verbose shows it; progress lines are compact without a terminal;
a process-pool worker's run logs reach the command's terminal."""

from __future__ import annotations

import io
import logging
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from rich.console import Console

from app.terminal import TerminalHandler
from tasks import logs


@pytest.fixture
def terminal(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[io.StringIO, Path]]:
    """The command's logging set up as ``_run_flow`` does (``verbose`` from the test's parameter);
    yields the terminal's text and the log file. The process's logging is put back afterwards."""
    root, rsl_rl, task_runs = logging.getLogger(), logging.getLogger("rsl_rl"), logging.getLogger("prefect.task_runs")
    saved = (root.level, list(root.handlers), rsl_rl.level, list(task_runs.filters))
    out, log_file = io.StringIO(), tmp_path / "run.log"
    handler = TerminalHandler(Console(file=out, width=200), verbose=request.param, own_api=True)
    logs.configure(str(log_file), handler)
    try:
        with handler:
            yield out, log_file
    finally:
        for h in root.handlers:
            if h not in saved[1]:
                h.close()
        root.setLevel(saved[0])
        root.handlers[:] = saved[1]
        rsl_rl.setLevel(saved[2])
        task_runs.filters[:] = saved[3]
        logging.captureWarnings(False)


# the record itself, not a warning that quotes the line of source emitting it
VIEW_AT_RECORD = re.compile(r"^\S+ (?:\w+ )?(?:prefect\.flow_runs: )?View at", re.MULTILINE)


def _chatter_and_summary() -> None:
    import rsl_rl.utils.logger

    import touch2robot.teachers.train  # noqa: F401  (routes rsl-rl's prints to its logger)

    logging.getLogger("huggingface_hub.hub_mixin").warning("Failed to resolve installed pip version")
    logging.getLogger("lerobot.configs.policies").warning("Device 'None' is not available. Switching to 'cpu'.")
    rsl_rl.utils.logger.print("Learning iteration 0/4")  # type: ignore[attr-defined]
    flow_run = logging.getLogger("prefect.flow_runs")
    flow_run.info("View at http://127.0.0.1:40049/runs/flow-run/5848c4e5")
    flow_run.info("Finished in state Completed()")
    flow_run.info("teachers: pick    touch2robot      success 0.00  contact F1 0.443")
    logging.getLogger("tasks.student").warning("student full: no validation windows")
    logging.getLogger("lerobot.policies").error("CUDA out of memory")


@pytest.mark.parametrize("terminal", [False], indirect=True)
def test_default_verbosity_keeps_library_chatter_in_the_log_file(terminal: tuple[io.StringIO, Path]) -> None:
    out, log_file = terminal
    _chatter_and_summary()
    shown, kept = out.getvalue(), log_file.read_text()
    for chatter in ("pip version", "Switching to 'cpu'", "Learning iteration", "Finished in state"):
        assert chatter not in shown
        assert chatter in kept
    for wanted in (
        "contact F1 0.443",
        "WARNING tasks.student: student full: no validation windows",
        "ERROR lerobot.policies: CUDA out of memory",
    ):
        assert wanted in shown
    assert not VIEW_AT_RECORD.search(shown)  # the command's own API ends with it


@pytest.mark.parametrize("terminal", [True], indirect=True)
def test_verbose_shows_library_chatter(terminal: tuple[io.StringIO, Path]) -> None:
    out, _ = terminal
    _chatter_and_summary()
    shown = out.getvalue()
    for chatter in ("pip version", "Switching to 'cpu'", "Learning iteration 0/4", "Finished in state", "contact F1"):
        assert chatter in shown
    assert not VIEW_AT_RECORD.search(shown)


def _progress(handler: logging.Handler, message: str) -> None:
    handler.handle(logging.makeLogRecord({"name": logs.PROGRESS_LOGGER, "levelno": logging.INFO, "msg": message}))


def test_progress_without_a_terminal_is_the_last_line_and_one_a_minute() -> None:
    out = io.StringIO()
    with TerminalHandler(Console(file=out, width=200)) as handler:
        for it in range(1, 41):
            _progress(
                handler, f"teacher pick/touch2robot: iteration {it}/40, mean return {it / 10:.3g}, ETA 0:00:{40 - it}"
            )
    assert out.getvalue().count("teacher pick/touch2robot") == 1  # a training shorter than a minute
    assert "iteration 40/40, mean return 4" in out.getvalue()


def test_a_workers_run_logs_reach_the_terminal() -> None:
    """What a process-pool worker's task run logs arrives as the payload Prefect forwards to the API."""
    out = io.StringIO()
    handler = TerminalHandler(Console(file=out, width=200))
    process = logs.forward_worker_logs()
    logs.show_worker_logs_with(handler)
    try:
        for level, name, message in (
            (logging.INFO, logs.PROGRESS_LOGGER, "policy pick/touch2robot: update 40/40, loss 1.0013"),
            (logging.INFO, "prefect.task_runs", "Finished in state Completed()"),
            (logging.DEBUG, "prefect.task_runs", "Loading weights from local directory"),
            (logging.WARNING, "prefect.task_runs", "quarantined x.mcap: truncated"),
        ):
            payload = {"name": name, "level": level, "message": message, "timestamp": "2026-12-04T23:49:34.699Z"}
            assert process("log", payload) == ("log", payload)  # still sent on to the API
    finally:
        logs.show_worker_logs_with(None)
    assert "update 40/40, loss 1.0013" in out.getvalue()
    assert "WARNING quarantined x.mcap: truncated" in out.getvalue()
    assert "Finished in state" not in out.getvalue() and "Loading weights" not in out.getvalue()


def test_the_verbose_flag_is_global() -> None:
    from typer.testing import CliRunner

    from app.cli import app, session

    assert CliRunner().invoke(app, ["--verbose", "sim", "--help"]).exit_code == 0
    assert session.verbose and session.command == "sim"
    assert CliRunner().invoke(app, ["sim", "--help"]).exit_code == 0
    assert not session.verbose
