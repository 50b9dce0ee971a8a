"""The app of the command's own Prefect API server (``app.local_server.PrefectApi`` runs it under uvicorn):
Prefect's ``create_app``, with every SQLite write transaction begun IMMEDIATE.

Why: Prefect begins most transactions DEFERRED. One that reads and then writes while another connection
writes (the server's event persister and task-run recorder write bursts as a flow run ends) gets SQLite's
SQLITE_BUSY at once, without waiting out the busy timeout; the server answers 503, and Prefect's client
sleeps 2 s before it tries again. A cached smoke re-run met that on 2 to 4 subflow starts, 2 s each, about
a quarter of its time beyond the API start (bench/rerun.py). An IMMEDIATE transaction takes the write lock
at its start, so it waits for the other writer (milliseconds) instead. Only this process imports Prefect's
server."""

from __future__ import annotations

from collections.abc import AsyncGenerator
from contextlib import asynccontextmanager
from typing import Any


def _immediate_transactions() -> None:
    from prefect.server.database import configurations

    deferred = configurations.AioSqliteConfiguration.begin_transaction
    if getattr(deferred, "_touch2robot_immediate", False):
        return

    @asynccontextmanager
    async def begin_transaction(self: Any, session: Any, with_for_update: bool = False) -> AsyncGenerator[Any, None]:
        async with deferred(self, session, with_for_update=True) as transaction:
            yield transaction

    begin_transaction._touch2robot_immediate = True  # type: ignore[attr-defined]
    configurations.AioSqliteConfiguration.begin_transaction = begin_transaction  # type: ignore[method-assign]


def create_app() -> Any:
    """uvicorn's ``--factory`` entry point."""
    from prefect.server.api.server import create_app as prefect_app

    _immediate_transactions()
    return prefect_app()
