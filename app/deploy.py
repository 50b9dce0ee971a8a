"""Register the deployments of ``prefect.yaml`` with a Prefect server: the programmatic
``prefect deploy --all``, with the work pool chosen by the caller.

Lives in the app shell, not in the ``touch2robot`` library, because the library stays free
of Prefect imports (DESIGN.md); it configures the environment as the flows do, so the deploy
talks to the same Prefect profile and API.

    touch2robot deploy --pool touch2robot-local        # the CLI wraps deploy_all
    python -m app.deploy --pool touch2robot-docker   # same, without the CLI

``prefect.yaml`` lists one entry per flow; ``definitions.work_pools`` names the pools
(variant key -> pool). Deploying to a pool registers every entry on that pool, named
after the variant (``ingest/local``, ``ingest/docker``), so both sets can live on one
server. A pool that ``prefect.yaml`` does not name (a lab's own) is accepted too; its
deployments are named after the pool."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from uuid import UUID

import flows as _configures_environment  # noqa: F401  # isort: skip  before Prefect is imported
import yaml
from prefect import Flow, get_client
from prefect.client.schemas.actions import WorkPoolCreate
from prefect.deployments.runner import RunnerDeployment
from prefect.exceptions import ObjectNotFound
from prefect.settings import get_current_settings
from prefect.workers.base import BaseWorker

PROJECT_ROOT = Path(__file__).resolve().parents[1]
PREFECT_YAML = PROJECT_ROOT / "prefect.yaml"
DEFAULT_POOL = "touch2robot-local"

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PoolSpec:
    """A work pool as ``prefect.yaml``'s ``definitions.work_pools`` describes it."""

    variant: str
    name: str
    type: str = "process"
    work_queue_name: str = "default"
    job_variables: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class DeploymentSpec:
    """One ``deployments:`` entry of ``prefect.yaml``."""

    entrypoint: str
    description: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)
    tags: tuple[str, ...] = ()

    @property
    def flow(self) -> str:
        """The flow function's name (``flows/ingest.py:ingest`` -> ``ingest``)."""
        return self.entrypoint.rsplit(":", 1)[-1]


def read_config(config: Path = PREFECT_YAML) -> tuple[dict[str, PoolSpec], list[DeploymentSpec]]:
    """Pools (by pool name) and deployment entries of a ``prefect.yaml``."""
    data = yaml.safe_load(Path(config).read_text()) or {}
    pools = {}
    for variant, p in ((data.get("definitions") or {}).get("work_pools") or {}).items():
        spec = PoolSpec(
            variant,
            p["name"],
            p.get("type", "process"),
            p.get("work_queue_name", "default"),
            dict(p.get("job_variables") or {}),
        )
        pools[spec.name] = spec
    deployments = [
        DeploymentSpec(
            d["entrypoint"], d.get("description", ""), dict(d.get("parameters") or {}), tuple(d.get("tags") or ())
        )
        for d in data.get("deployments") or []
    ]
    return pools, deployments


def _ensure_pool(pool: PoolSpec) -> None:
    """Create the work pool unless it exists (the CLI's ``prefect work-pool create``)."""
    with get_client(sync_client=True) as client:
        try:
            client.read_work_pool(pool.name)
            return
        except ObjectNotFound:
            pass
        worker_class = BaseWorker.get_worker_class_from_type(pool.type)
        if worker_class is None:
            raise ValueError(f"work pool type {pool.type!r} has no worker installed here (process is built in)")
        client.create_work_pool(
            WorkPoolCreate(
                name=pool.name, type=pool.type, base_job_template=worker_class.get_default_base_job_template()
            )
        )
        log.info("created work pool %s (%s)", pool.name, pool.type)


def deploy_all(
    pool: str = DEFAULT_POOL,
    *,
    flows: Sequence[str] | None = None,
    config: Path = PREFECT_YAML,
) -> dict[str, UUID]:
    """Register every deployment of ``config`` (or those of the named ``flows``) on the
    work pool ``pool``, creating the pool if it does not exist.

    The Prefect server is the one the environment names (PREFECT_API_URL or the active
    Prefect profile); the deployments run the code of the folder holding ``config``,
    so call this where the worker will run (a checkout, or the worker's image).
    Returns ``{"<flow>/<deployment>": deployment id}``."""
    if not get_current_settings().api.url:
        raise RuntimeError(
            "deployments need a Prefect server: start one (`uv run prefect server start`, or the compose stack "
            "in infra/) and set PREFECT_API_URL, e.g. http://127.0.0.1:4200/api"
        )
    config = Path(config).resolve()
    pools, specs = read_config(config)
    target = pools.get(pool, PoolSpec(variant=pool, name=pool))
    if flows is not None:
        unknown = set(flows) - {s.flow for s in specs}
        if unknown:
            raise ValueError(
                f"no deployment for flow(s) {sorted(unknown)} in {config}; known: {sorted(s.flow for s in specs)}"
            )
        specs = [s for s in specs if s.flow in flows]
    _ensure_pool(target)
    ids: dict[str, UUID] = {}
    for spec in specs:
        # from_source with a folder loads the flow from there and records that folder as
        # the runs' working directory (a set_working_directory pull step), as `prefect deploy` does.
        # Prefect's async_dispatch types these sync calls as "value or coroutine": hence the ignores
        flow_obj: Flow[..., Any] = Flow.from_source(source=str(config.parent), entrypoint=spec.entrypoint)  # pyright: ignore[reportAssignmentType]
        deployment: RunnerDeployment = flow_obj.to_deployment(  # pyright: ignore[reportAssignmentType]
            name=target.variant,
            description=spec.description,
            parameters=spec.parameters,
            tags=list(spec.tags),
            work_pool_name=target.name,
            work_queue_name=target.work_queue_name,
            job_variables=target.job_variables,
        )
        ids[f"{flow_obj.name}/{target.variant}"] = deployment.apply(work_pool_name=target.name)  # pyright: ignore[reportArgumentType]
    return ids


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m app.deploy``: the same as ``touch2robot deploy``."""
    parser = argparse.ArgumentParser(
        prog="python -m app.deploy", description="Register the deployments of prefect.yaml on a work pool."
    )
    parser.add_argument("--pool", default=DEFAULT_POOL, help=f"work pool (default {DEFAULT_POOL}; created if missing)")
    parser.add_argument("--flow", action="append", dest="flows", help="only this flow's deployment (repeatable)")
    parser.add_argument("--config", type=Path, default=PREFECT_YAML, help="the prefect.yaml to read")
    args = parser.parse_args(argv)
    for name, deployment_id in deploy_all(args.pool, flows=args.flows, config=args.config).items():
        print(f"{name}\t{deployment_id}")


if __name__ == "__main__":
    main()
