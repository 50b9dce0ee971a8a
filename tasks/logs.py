"""Where a run's log records go, in the command's process and in its task runner's worker
processes alike: everything into the run's log file (``TOUCH2ROBOT_LOG_FILE``), the terminal only
what the command shows (app/terminal.py); and the progress lines of the trainings.

A process-pool worker writes nothing to the terminal unless ``TOUCH2ROBOT_VERBOSE`` is set: what
it has to show (its task runs' records, progress lines included) reaches the command's process as
the run logs Prefect forwards from its workers to the API, and is shown there
(``forward_worker_logs``). Its output that is no log record (a library's print, a C library's
warning) goes to the log file, not across the command's progress display."""

from __future__ import annotations

import datetime
import logging
import os
import sys
import time
from collections.abc import Callable
from typing import Any, Protocol

LOG_FILE_ENV = "TOUCH2ROBOT_LOG_FILE"
VERBOSE_ENV = "TOUCH2ROBOT_VERBOSE"
# the child of the run loggers that carries progress lines (see TrainingProgress)
PROGRESS_LOGGER = "prefect.task_runs.progress"
FORMAT = "%(asctime)s %(levelname)-7s %(processName)s %(name)s: %(message)s"
# libraries that log every request at INFO
QUIET_LIBRARIES = ("httpx", "httpcore", "urllib3", "matplotlib", "PIL", "numba")


class DemotePrints(logging.Filter):
    """Prefect logs what a task run prints (``log_prints``) at INFO; in a task that is library chatter
    (our tasks log, they do not print): debug level. Flows' prints (their summaries) keep INFO. The
    record names print's caller, so the filter looks for Prefect's print patch on the stack."""

    def __init__(self) -> None:
        super().__init__()
        from prefect.logging.loggers import print_as_log

        self._print_code = print_as_log.__code__

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno == logging.INFO:
            frame = sys._getframe(1)
            for _ in range(12):  # logging's own frames, then print_as_log
                if frame is None:
                    break
                if frame.f_code is self._print_code:
                    record.levelno, record.levelname = logging.DEBUG, "DEBUG"
                    break
                frame = frame.f_back
        return True


def configure(log_file: str | None, terminal: logging.Handler | None) -> None:
    """Log records of this process: all (debug level for rsl-rl's dumps, INFO for the rest) into
    ``log_file``; on the terminal through ``terminal`` instead of Prefect's console handler when
    given. Call after importing Prefect (it sets logging up when imported)."""
    from prefect.logging.handlers import PrefectConsoleHandler

    root = logging.getLogger()
    root.setLevel(logging.INFO)
    logging.getLogger("rsl_rl").setLevel(logging.DEBUG)
    for name in QUIET_LIBRARIES:
        logging.getLogger(name).setLevel(logging.WARNING)
    logging.getLogger("prefect.task_runs").addFilter(DemotePrints())
    logging.captureWarnings(True)  # warnings.warn of libraries: the py.warnings logger
    if log_file:
        to_file = logging.FileHandler(log_file, encoding="utf-8")
        to_file.setFormatter(logging.Formatter(FORMAT))
        root.addHandler(to_file)
    if terminal is not None:
        for handler in [h for h in root.handlers if isinstance(h, PrefectConsoleHandler)]:
            root.removeHandler(handler)
        root.addHandler(terminal)


def configure_worker() -> None:
    """A task runner's worker process (its initializer): the run's log file; the terminal only
    with ``TOUCH2ROBOT_VERBOSE`` (Prefect's console handler), else its stdout and stderr go to
    the log file as well."""
    log_file = os.environ.get(LOG_FILE_ENV)
    if log_file:  # the run's folder may have moved or gone since the command began: a worker must still start
        os.makedirs(os.path.dirname(log_file), exist_ok=True)
    if os.environ.get(VERBOSE_ENV) == "1" or not log_file:
        configure(log_file, None)
        return
    configure(log_file, logging.NullHandler())
    sys.stdout.flush()
    sys.stderr.flush()
    fd = os.open(log_file, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)


# Where the command's process shows the run logs its workers forward (None: not shown, the
# workers print them themselves)
_worker_logs_to: logging.Handler | None = None


def show_worker_logs_with(handler: logging.Handler | None) -> None:
    global _worker_logs_to
    _worker_logs_to = handler


class WorkerMessageProcessor(Protocol):
    """What ProcessPoolTaskRunner calls with each message of a worker (Prefect's private
    ``_SubprocessMessageProcessor``, whose parameter names an implementation must keep)."""

    def __call__(self, message_type: str, message_payload: Any) -> tuple[str, Any] | None: ...


def forward_worker_logs() -> WorkerMessageProcessor:
    """A ProcessPoolTaskRunner message processor (factory): each run log a worker forwards to the
    API goes to the handler of ``show_worker_logs_with`` too, as a log record of this process."""

    def process(message_type: str, message_payload: Any) -> tuple[str, Any]:
        handler = _worker_logs_to
        level = (
            int(message_payload.get("level", logging.INFO))
            if message_type == "log" and isinstance(message_payload, dict)
            else 0
        )
        if handler is not None and level >= max(handler.level, 1):
            created = datetime.datetime.fromisoformat(message_payload["timestamp"]).timestamp()
            record = logging.makeLogRecord(
                {
                    "name": message_payload.get("name", ""),
                    "levelno": level,
                    "levelname": logging.getLevelName(level),
                    "msg": message_payload.get("message", ""),
                    "created": created,
                    "msecs": (created % 1) * 1000,
                }
            )
            handler.handle(record)
        return message_type, message_payload

    return process


class TrainingProgress:
    """An ``on_log(step, metrics)`` hook reporting a training's progress as one compact line, e.g.
    ``teacher pick/touch2robot: iteration 3/40, mean return 1.23, ETA 0:02:10``, on the logger
    ``PROGRESS_LOGGER`` of the task run: at the first call, then at most every ``every_s`` seconds,
    and at the last step. The run's log (Prefect UI) keeps them; the terminal draws them as a
    progress bar per training (app/terminal.py).

    ``done(step)`` is the count of units finished at ``step`` (rsl-rl counts iterations from 0);
    ``headline(metrics)`` the figure to show, or None for a call that is no unit's end (rsl-rl's
    wall-clock series); ``total`` the units of the whole training."""

    def __init__(
        self,
        label: str,
        unit: str,
        total: int,
        headline: Callable[[dict[str, float]], str | None],
        done: Callable[[int], int] = lambda step: step,
        every_s: float = 10.0,
    ) -> None:
        from prefect import get_run_logger
        from prefect.logging.loggers import PrefectLogAdapter

        self.label, self.unit, self.total, self.headline, self.done, self.every_s = (
            label,
            unit,
            total,
            headline,
            done,
            every_s,
        )
        run_logger = get_run_logger()
        # a run's logger is Prefect's adapter (its getChild keeps the run's extra), or a plain
        # Logger where Prefect's run loggers are disabled; a bare LoggerAdapter has no getChild
        assert isinstance(run_logger, logging.Logger | PrefectLogAdapter)
        self.logger = run_logger.getChild("progress")
        self._start: tuple[float, int] | None = None  # (time, units done) at the first call
        self._last_s = -float("inf")

    def __call__(self, step: int, metrics: dict[str, float]) -> None:
        figure = self.headline(metrics)
        if figure is None:
            return
        done, now = self.done(step), time.monotonic()
        if self._start is None:
            self._start = (now, done)
        if now - self._last_s < self.every_s and done < self.total:
            return
        self._last_s = now
        parts = [f"{self.label}: {self.unit} {done}/{self.total}", *([figure] if figure else [])]
        started_s, started_done = self._start
        if started_done < done < self.total:
            eta = (now - started_s) / (done - started_done) * (self.total - done)
            parts.append(f"ETA {datetime.timedelta(seconds=round(eta))}")
        self.logger.info(", ".join(parts))


def both(*hooks: Callable[[int, dict[str, float]], None]) -> Callable[[int, dict[str, float]], None]:
    """One ``on_log`` calling each hook in turn."""

    def on_log(step: int, metrics: dict[str, float]) -> None:
        for hook in hooks:
            hook(step, metrics)

    return on_log
