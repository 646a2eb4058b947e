"""The consoles the ``gridplace`` commands print with, and small wording helpers.

Lines are never wrapped by the program (``soft_wrap``): a path, a URL or a command pasted
from the output is whole, and a terminal wraps long lines on screen by itself. Tables keep
their natural width when the output is not a terminal (a pipe, a file, a CI log), where rich
would otherwise squeeze them into 80 columns (``ve… ac… 35…``); on a terminal they fit it.
"""

from __future__ import annotations

from rich.console import Console
from rich.measure import Measurement
from rich.table import Table

_UNBOUNDED = 1_000_000  # columns: measure a table without a width limit


def cli_console(stderr: bool = False) -> Console:
    """A console that does not wrap printed lines."""
    return Console(stderr=stderr, soft_wrap=True)


def print_table(console: Console, table: Table) -> None:
    """``table`` at the terminal's width, or at its natural width when not on a terminal."""
    if console.is_terminal:
        console.print(table)
        return
    width = Measurement.get(console, console.options.update_width(_UNBOUNDED), table).maximum
    # a console's print never renders wider than the console: print through a wider one
    Console(file=console.file, width=max(console.width, width)).print(table)


def plural(n: int, one: str, many: str | None = None) -> str:
    """``"1 query"``, ``"2 queries"``: ``n`` with the word it counts."""
    return f"{n:,} {one if n == 1 else (many or one + 's')}"
