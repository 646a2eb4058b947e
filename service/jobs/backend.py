"""The training-backend interface the service layer talks to, and the choice between the
embedded process pool and RQ workers."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from service.encoding import ModelParams
from service.registry import JobInfo, Registry, RouteSource
from service.settings import Settings


@runtime_checkable
class TrainingBackend(Protocol):
    """Runs training jobs; their state lives in the registry's job table."""

    def submit(
        self,
        map_name: str,
        route: Path,
        params: ModelParams,
        extractor: dict[str, Any] | None,
        idempotency_key: str | None,
        *,
        source: RouteSource | None = None,
        force: bool = False,
    ) -> JobInfo:
        """Queue training of ``route`` (an ``.npy`` (N, d) file under ``data_dir``) as the next
        version of ``map_name``. The same ``(map_name, idempotency_key)`` again returns the
        existing job without training twice, and so does the same ``source`` with the same
        parameters and extractor unless ``force`` (that answer says ``reused``)."""
        ...

    def get_job(self, job_id: str) -> JobInfo: ...

    def queue_depth(self) -> int:
        """Jobs (or job parts) waiting to run."""
        ...

    def check_available(self) -> None:
        """Raise :class:`~service.errors.UnavailableError` when jobs cannot be queued now."""
        ...

    def close(self) -> None: ...


def make_backend(settings: Settings, registry: Registry) -> TrainingBackend:
    """RQ workers when ``settings.redis_url`` is set, else the embedded process pool. Either
    way, workspaces that finished jobs left behind are swept first."""
    from service.jobs.workspace import sweep_workspaces

    sweep_workspaces(registry)
    if settings.redis_url:
        from service.jobs.rq_backend import RQBackend

        return RQBackend(settings, registry)
    from service.jobs.embedded import EmbeddedBackend

    return EmbeddedBackend(settings, registry)
