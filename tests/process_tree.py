"""The test session's process tree, read from ``/proc`` (Linux).

The session makes itself a *child subreaper* (``prctl(PR_SET_CHILD_SUBREAPER)``), so a process
orphaned by anything the tests started (a server's forkserver, a pool worker whose parent was
killed) is reparented to pytest instead of init, and stays visible to
:func:`live_descendants` until it exits.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import time
from pathlib import Path

PR_SET_CHILD_SUBREAPER = 36
PROC = Path("/proc")


def supported() -> bool:
    return sys.platform.startswith("linux") and PROC.is_dir()


def become_subreaper() -> bool:
    """Adopt this process's orphaned descendants (True when the kernel agreed)."""
    if not supported():
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    return int(libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)) == 0


def _stat(pid: int) -> tuple[int, str] | None:
    """``(ppid, state)`` of a process, or None once it is gone."""
    try:
        text = (PROC / str(pid) / "stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()  # the command name may hold spaces
    return int(fields[1]), fields[0]


def process_table() -> dict[int, tuple[int, str]]:
    table = {}
    for entry in PROC.iterdir():
        if entry.name.isdigit():
            stat = _stat(int(entry.name))
            if stat is not None:
                table[int(entry.name)] = stat
    return table


def descendants(root: int, include_zombies: bool = False) -> list[int]:
    """Every process below ``root`` (children, grandchildren, …)."""
    table = process_table()
    children: dict[int, list[int]] = {}
    for pid, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    out, todo = [], list(children.get(root, []))
    while todo:
        pid = todo.pop()
        todo.extend(children.get(pid, []))
        if include_zombies or table[pid][1] != "Z":
            out.append(pid)
    return sorted(out)


def alive(pid: int) -> bool:
    stat = _stat(pid)
    return stat is not None and stat[1] != "Z"


def reap_zombies() -> None:
    """Collect exited children (orphans adopted by the subreaper end as our zombies)."""
    for pid in descendants(os.getpid(), include_zombies=True):
        stat = _stat(pid)
        if stat is not None and stat[1] == "Z" and stat[0] == os.getpid():
            try:
                os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:
                pass


def live_descendants(grace_s: float = 0.0, exempt: frozenset[int] = frozenset()) -> list[int]:
    """This process's living descendants but ``exempt`` (their descendants are not exempt),
    after waiting up to ``grace_s`` for them to exit."""
    deadline = time.monotonic() + grace_s
    while True:
        reap_zombies()
        left = [pid for pid in descendants(os.getpid()) if pid not in exempt]
        if not left or time.monotonic() >= deadline:
            return left
        time.sleep(0.1)


def wait_gone(pids: list[int], timeout_s: float) -> list[int]:
    """The ``pids`` still alive after up to ``timeout_s`` seconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        reap_zombies()
        left = [p for p in pids if alive(p)]
        if not left or time.monotonic() >= deadline:
            return left
        time.sleep(0.05)


def describe(pid: int) -> str:
    try:
        raw = (PROC / str(pid) / "cmdline").read_bytes()
    except OSError:
        return f"{pid} (gone)"
    command = raw.replace(b"\0", b" ").decode(errors="replace").strip()
    return f"{pid} {command[:200]}"


def kill_all(pids: list[int]) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    wait_gone(pids, 5.0)
