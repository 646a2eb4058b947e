"""The ``gridplace`` command line."""

from __future__ import annotations

import typer

from service.cli import bench as bench_commands
from service.cli import demo_commands
from service.cli import model_commands
from service.cli import extract_commands, serve_commands
from service.cli import worker_commands
from service.cli import client_commands
from service.cli.pitch import HELP

app = typer.Typer(
    name="gridplace",
    help=HELP,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
model_commands.register(app)
demo_commands.register(app)
serve_commands.register(app)
extract_commands.register(app)
worker_commands.register(app)
client_commands.register(app)
app.add_typer(bench_commands.app, name="bench")


def main() -> None:
    app()
