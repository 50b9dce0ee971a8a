"""Where a flow's fan-out runs: the ``runner`` section of a profile.

Plain data (no Prefect import): ``tasks.runners`` turns it into a Prefect task runner.
A laptop keeps the default (a thread pool, measured fastest on 2 cores for the ingest
fan-out, whose work is mostly NumPy/Arrow/zstd code that releases the GIL); a lab points
``dask_address`` at its Dask scheduler and the same flows fan out over the cluster."""

from __future__ import annotations

from typing import Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator


class RunnerConfig(BaseModel):
    """Task runner of the fan-out stages.

    - ``threads``: Prefect's ThreadPoolTaskRunner (``max_workers`` threads).
    - ``processes``: Prefect's ProcessPoolTaskRunner (``max_workers`` processes).
    - ``dask``: prefect-dask's DaskTaskRunner, on the scheduler at ``dask_address``
      (e.g. ``tcp://scheduler:8786``) or, without one, on a LocalCluster of
      ``n_workers`` processes started for the flow run (needs the ``dask`` extra).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["threads", "processes", "dask"] = "threads"
    max_workers: int | None = Field(
        default=None, ge=1, description="pool size of threads/processes; None: the CPU count"
    )
    dask_address: str | None = Field(
        default=None, description="address of an existing Dask scheduler (production); None: a LocalCluster"
    )
    n_workers: int = Field(
        default=2, ge=1, description="LocalCluster worker processes (kind dask without dask_address)"
    )
    threads_per_worker: int = Field(default=1, ge=1, description="threads per LocalCluster worker process")

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        # a scheduler address under another kind would be silently ignored: say so instead
        if self.dask_address is not None and self.kind != "dask":
            raise ValueError(f"dask_address is only used with kind 'dask' (kind is {self.kind!r})")
        if self.dask_address is not None and "://" not in self.dask_address:
            raise ValueError(f"dask_address {self.dask_address!r} needs a scheme, e.g. tcp://scheduler:8786")
        return self
