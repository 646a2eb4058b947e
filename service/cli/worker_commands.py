"""``gridplace worker``: an RQ worker that trains routes chunk by chunk."""

from __future__ import annotations

from typing import Annotated

import typer

from service.cli.errors import cli_errors
from service.errors import InvalidParameterError
from service.jobs.worker import (
    DEFAULT_HEARTBEAT_GRACE_S,
    DEFAULT_MAINTENANCE_INTERVAL_S,
    DEFAULT_MONITORING_INTERVAL_S,
)
from service.settings import get_settings


@cli_errors
def worker(
    redis_url: Annotated[
        str | None, typer.Option("--redis-url", help="Redis URL (default GRIDPLACE_REDIS_URL)")
    ] = None,
    queue: Annotated[
        str | None, typer.Option("--queue", help="queue name (default GRIDPLACE_QUEUE_NAME)")
    ] = None,
    burst: Annotated[bool, typer.Option("--burst", help="exit once the queue is empty")] = False,
    name: Annotated[str | None, typer.Option("--name", help="worker name (unique)")] = None,
    monitoring_interval: Annotated[
        int,
        typer.Option("--monitoring-interval", min=1, help="heartbeat interval while training (s)"),
    ] = DEFAULT_MONITORING_INTERVAL_S,
    heartbeat_grace: Annotated[
        int,
        typer.Option(
            "--heartbeat-grace", min=1,
            help="a silent worker's job is abandoned this long after its last heartbeat (s)",
        ),
    ] = DEFAULT_HEARTBEAT_GRACE_S,
    maintenance_interval: Annotated[
        int,
        typer.Option(
            "--maintenance-interval", min=1, help="how often to clean up jobs of dead workers (s)"
        ),
    ] = DEFAULT_MAINTENANCE_INTERVAL_S,
) -> None:
    """Run an RQ training worker; start several, on any host that shares the data directory."""
    from service.jobs.worker import run_worker

    settings = get_settings()
    url = redis_url or settings.redis_url
    if not url:
        raise InvalidParameterError("no Redis URL: pass --redis-url or set GRIDPLACE_REDIS_URL")
    run_worker(
        url, queue or settings.queue_name, burst=burst, name=name,
        monitoring_interval_s=monitoring_interval, heartbeat_grace_s=heartbeat_grace,
        maintenance_interval_s=maintenance_interval, log_level=settings.log_level,
    )  # fmt: skip


def register(app: typer.Typer) -> None:
    app.command("worker")(worker)
