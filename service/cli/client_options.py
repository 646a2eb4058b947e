"""What every ``gridplace client …`` command shares: the server options (``--url``,
``--token``, ``--timeout``, ``--json``, the wait options), the client they open, and how an
answer is printed."""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Annotated, Any

import typer
from pydantic import BaseModel

from service.cli.console import cli_console
from service.client import GridplaceClient

console = cli_console()

Url = Annotated[str | None, typer.Option("--url", envvar="GRIDPLACE_URL", show_envvar=True,
                                         help="server URL (default http://127.0.0.1:8080)")]  # fmt: skip
Token = Annotated[str | None, typer.Option("--token", envvar="GRIDPLACE_ADMIN_TOKEN", show_envvar=True,
                                           show_default=False, help="admin bearer token")]  # fmt: skip
MapName = Annotated[str, typer.Argument(metavar="MAP", help="map name")]
Timeout = Annotated[float, typer.Option(help="seconds per request")]
AsJson = Annotated[bool, typer.Option("--json", help="print the server's answer as JSON")]
WaitTimeout = Annotated[float, typer.Option(help="seconds to wait with --wait")]
ConditionOption = Annotated[str | None, typer.Option(
    "--condition", help="the condition the queries were taken in: one the map's version "
    "recorded from tagged traversals (e.g. season=winter), 'reference', or 'auto' (inferred "
    "from the queries); they are standardised by its statistics")]  # fmt: skip


@contextmanager
def open_client(url: str | None, token: str | None, timeout: float) -> Iterator[GridplaceClient]:
    with GridplaceClient(url, token=token, timeout=timeout) as gp:
        yield gp


def print_json(value: BaseModel | Sequence[BaseModel]) -> None:
    if isinstance(value, BaseModel):
        typer.echo(value.model_dump_json(indent=2))
    else:
        typer.echo(json.dumps([v.model_dump(mode="json") for v in value], indent=2))


def when(value: Any) -> str:
    return value.strftime("%Y-%m-%d %H:%M:%S") if value is not None else "-"
