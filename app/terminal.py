"""The terminal of a flow command: the log records worth a person's attention, a live progress bar
per running training, and nothing else (the run's log file has it all, tasks/logs.py).

At default verbosity it shows: a line per stage (flow run) starting, the flows' summaries and the
tasks' own messages, warnings and errors of the project, errors of anything, and the trainings'
progress. Hidden there: Prefect's per-run chatter ("Finished in state Completed()", the task
runner in use), libraries' records below ERROR (MLflow's environment export and pickle warnings,
LeRobot's device warnings, ...), what tasks print, and Prefect's "View at <url>" links when they
point at the command's own temporary API, which ends with it. ``verbose`` shows every record."""

from __future__ import annotations

import logging
import re
import time
from datetime import datetime

from rich.console import Console
from rich.live import Live
from rich.markup import escape
from rich.progress import BarColumn, Progress, TaskID, TextColumn

from tasks.logs import PROGRESS_LOGGER

RUN_LOGGERS = ("prefect.flow_runs", "prefect.task_runs")
OWN_LOGGERS = (*RUN_LOGGERS, "touch2robot", "tasks", "flows", "app")
STAGE_START = re.compile(r"^Beginning (?:sub)?flow run '[^']*' for flow '(?P<flow>[^']+)'")
PROGRESS = re.compile(r"^(?P<label>.+?): (?P<unit>\w+) (?P<done>\d+)/(?P<total>\d+)(?:, (?P<detail>.*))?$")
# without a terminal (a file, CI) a running training's line is printed at most this often
PLAIN_PROGRESS_EVERY_S = 60.0


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


class TerminalHandler(logging.Handler):
    """A logging handler drawing a flow command's records on ``console`` (see the module docstring).
    Use it as a context manager around the flow: on a terminal it keeps the progress bars live
    below the printed lines; elsewhere a training's progress is a plain line when it ends and, while
    it runs, every ``PLAIN_PROGRESS_EVERY_S`` seconds."""

    def __init__(self, console: Console, verbose: bool = False, own_api: bool = False) -> None:
        super().__init__(logging.DEBUG if verbose else logging.INFO)
        self.console, self.verbose, self.own_api = console, verbose, own_api
        self.live_bars = console.is_terminal and not console.is_dumb_terminal and not verbose
        self.progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(bar_width=24),
            TextColumn("{task.completed:.0f}/{task.total:.0f} {task.fields[unit]}"),
            TextColumn("{task.fields[detail]}"),
            console=console,
        )
        self._bars: dict[str, TaskID] = {}
        self._printed_s: dict[str, float] = {}
        self._live: Live | None = None

    def __enter__(self) -> TerminalHandler:
        if self.live_bars:
            self._live = Live(self.progress, console=self.console, refresh_per_second=2, transient=True)
            self._live.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        if self._live is not None:
            self._live.stop()
            self._live = None

    def shown(self, record: logging.LogRecord) -> bool:
        """Whether the record reaches the terminal at this verbosity (progress aside)."""
        message = record.getMessage()
        if self.own_api and message.startswith("View at "):
            return False  # a link to the command's own API server, gone when the command ends
        if self.verbose or record.levelno >= logging.ERROR:
            return True
        if _within(record.name, RUN_LOGGERS):
            chatter = record.levelno < logging.WARNING and message.startswith(("Finished in state ", "View at "))
            return record.levelno >= logging.INFO and not chatter
        return record.levelno >= logging.WARNING and _within(record.name, OWN_LOGGERS)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            if record.name == PROGRESS_LOGGER and not self.verbose:
                self._progress(record)
            elif self.shown(record):
                self._print(record)
        except Exception:
            self.handleError(record)

    def _print(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if not self.verbose and (start := STAGE_START.match(message)):
            self.console.rule(f"[bold]{escape(start['flow'])}", align="left", style="dim")
            return
        clock = datetime.fromtimestamp(record.created).strftime("%H:%M:%S")
        level = {logging.WARNING: "[yellow]WARNING[/] ", logging.ERROR: "[red]ERROR[/] "}.get(
            record.levelno, "[bright_red]CRITICAL[/] " if record.levelno > logging.ERROR else ""
        )
        source = f"{escape(record.name)}: " if self.verbose or not _within(record.name, RUN_LOGGERS) else ""
        text = escape(message)
        if record.exc_info and record.exc_text is None:
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            text += "\n" + escape(record.exc_text)
        self.console.print(f"[dim]{clock}[/] {level}{source}{text}", soft_wrap=True, highlight=False)

    def _progress(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        line = PROGRESS.match(message)
        if line is None:
            self._print(record)
            return
        label, done, total = line["label"], int(line["done"]), int(line["total"])
        finished = done >= total
        if not self.live_bars:  # the last line, and one a minute of a training that runs longer
            now = time.monotonic()
            if finished or now - self._printed_s.setdefault(label, now) >= PLAIN_PROGRESS_EVERY_S:
                self._printed_s[label] = now
                self._print(record)
            return
        if finished:
            if label in self._bars:
                self.progress.remove_task(self._bars.pop(label))
            self._print(record)
            return
        fields = {"unit": f"{line['unit']}s", "detail": line["detail"] or ""}
        if label not in self._bars:
            self._bars[label] = self.progress.add_task(label, total=total, completed=done, **fields)
        else:
            self.progress.update(self._bars[label], total=total, completed=done, **fields)
