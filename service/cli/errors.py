"""Turning gridplace errors into a clear message and a non-zero exit code."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

import typer
from rich.markup import escape

from service.cli.console import cli_console
from service.errors import GridplaceError

P = ParamSpec("P")
R = TypeVar("R")
err_console = cli_console(stderr=True)


def cli_errors(fn: Callable[P, R]) -> Callable[P, R]:
    """Print a :class:`GridplaceError` as ``error [code]: message`` and exit 2."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        try:
            return fn(*args, **kwargs)
        except GridplaceError as exc:
            message = f"[bold red]error[/] \\[{exc.code}]: {escape(exc.message)}"
            err_console.print(message, highlight=False, soft_wrap=True)
            raise typer.Exit(code=2) from exc

    return wrapper
