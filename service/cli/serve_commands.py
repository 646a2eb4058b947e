"""``gridplace serve``: the REST model server, and gRPC in the same process when ``GRIDPLACE_GRPC_PORT`` is set."""

from __future__ import annotations

import inspect
import logging
from pathlib import Path
from typing import Annotated

import typer

from service.cli.errors import cli_errors
from service.settings import Settings


def _settings_help() -> str:
    """One paragraph, one line per setting (the help keeps a paragraph's line breaks)."""
    lines = ["Every setting is an environment variable (flags override them):"]
    for name, field in Settings.model_fields.items():
        default = field.default
        shown = "unset" if default is None else default
        lines.append(f"GRIDPLACE_{name.upper()}: {field.description} (default {shown})")
    return "\n".join(lines)


@cli_errors
def serve(
    host: Annotated[str | None, typer.Option(help="bind address [GRIDPLACE_HOST]")] = None,
    port: Annotated[int | None, typer.Option(help="REST port [GRIDPLACE_PORT]")] = None,
    grpc_port: Annotated[int | None, typer.Option(help="gRPC port, 0 = off [GRIDPLACE_GRPC_PORT]")] = None,
    data_dir: Annotated[Path | None, typer.Option(help="registry/artifacts/uploads [GRIDPLACE_DATA_DIR]")] = None,
    redis_url: Annotated[str | None, typer.Option(help="train on RQ workers [GRIDPLACE_REDIS_URL]")] = None,
    queue_name: Annotated[str | None, typer.Option(help="RQ queue [GRIDPLACE_QUEUE_NAME]")] = None,
    insecure_dev: Annotated[bool | None, typer.Option("--insecure-dev/--secure", help="admin without token [GRIDPLACE_INSECURE_DEV]")] = None,
    max_upload_mb: Annotated[int | None, typer.Option(help="largest upload in MiB [GRIDPLACE_MAX_UPLOAD_MB]")] = None,
    train_workers: Annotated[int | None, typer.Option(help="embedded training processes [GRIDPLACE_TRAIN_WORKERS]")] = None,
    job_timeout_s: Annotated[int | None, typer.Option(help="job time limit [GRIDPLACE_JOB_TIMEOUT_S]")] = None,
    reload_interval_s: Annotated[float | None, typer.Option(help="hot-swap poll period [GRIDPLACE_RELOAD_INTERVAL_S]")] = None,
    log_level: Annotated[str | None, typer.Option(help="[GRIDPLACE_LOG_LEVEL]")] = None,
) -> None:
    """Serve REST /v1 (OpenAPI at /docs), /healthz, /readyz, /metrics, and gRPC. The admin
    token is read from GRIDPLACE_ADMIN_TOKEN only (never a flag: it would show in `ps`).
    A port in use ends the command with exit code 2 before anything is served; Ctrl-C or
    SIGTERM shuts down gracefully (unfinished training jobs are marked failed) with exit 0."""
    from service.api.serving import serve_forever

    overrides = {k: v for k, v in dict(
        host=host, port=port, grpc_port=grpc_port, data_dir=data_dir, redis_url=redis_url,
        queue_name=queue_name, insecure_dev=insecure_dev, max_upload_mb=max_upload_mb,
        train_workers=train_workers, job_timeout_s=job_timeout_s,
        reload_interval_s=reload_interval_s, log_level=log_level,
    ).items() if v is not None}  # fmt: skip
    settings = Settings(**overrides)  # type: ignore[arg-type]  # flags override the environment
    logging.basicConfig(level=settings.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")  # fmt: skip
    if settings.admin_token is None and settings.insecure_dev:
        logging.getLogger("gridplace").warning("admin API open WITHOUT a token (insecure_dev)")
    serve_forever(settings)


def register(app: typer.Typer) -> None:
    app.command(help=f"{inspect.cleandoc(serve.__doc__ or '')}\n\n{_settings_help()}")(serve)
