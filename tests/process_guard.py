"""A pytest plugin: the test session leaves no process behind (``tests/conftest.py`` loads it;
``-p process_guard`` loads it into any session).

At start the session becomes a child subreaper, so whatever the tests start stays in its
process tree even when orphaned (a killed server's training pool, a forkserver). When the
session ends, every fixture has stopped what it started, and the pool joblib keeps for reuse
(``n_jobs`` > 1 in the library) is shut down; any descendant still alive after a short grace
period is listed, killed, and the session fails.

Exempt are only the helper processes the interpreter keeps for its whole life and that exit
with it: this process's multiprocessing forkserver and resource trackers (the stdlib's and
loky's). A process of theirs, such as a pool worker forked by the forkserver, is not exempt.
"""

from __future__ import annotations

import sys

import process_tree
import pytest

GRACE_S = 5.0  # processes asked to stop at the last teardown get this long to exit
_subreaper = pytest.StashKey[bool]()
_leaked: list[str] = []


def pytest_configure(config: pytest.Config) -> None:
    config.stash[_subreaper] = process_tree.become_subreaper()


def _stop_reusable_pools() -> None:
    """Shut down joblib's reusable loky executor if the tests made one start."""
    loky = sys.modules.get("joblib.externals.loky.reusable_executor")
    executor = getattr(loky, "_executor", None)
    if executor is not None:
        executor.shutdown(wait=True, kill_workers=True)


def _interpreter_helpers() -> frozenset[int]:
    """pids of this process's own forkserver and resource trackers (they exit with it)."""
    pids = set()
    for module, obj, attr in (
        ("multiprocessing.forkserver", "_forkserver", "_forkserver_pid"),
        ("multiprocessing.resource_tracker", "_resource_tracker", "_pid"),
        ("joblib.externals.loky.backend.resource_tracker", "_resource_tracker", "_pid"),
    ):
        pid = getattr(getattr(sys.modules.get(module), obj, None), attr, None)
        if isinstance(pid, int):
            pids.add(pid)
    return frozenset(pids)


def _stop_forkserver() -> None:
    """Stop this process's forkserver now rather than when the interpreter exits (it would
    otherwise outlive the printed summary by a moment)."""
    server = getattr(sys.modules.get("multiprocessing.forkserver"), "_forkserver", None)
    stop = getattr(server, "_stop", None)
    if callable(stop):
        stop()


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if not session.config.stash.get(_subreaper, False):
        return
    _stop_reusable_pools()
    left = process_tree.live_descendants(GRACE_S, exempt=_interpreter_helpers())
    _stop_forkserver()
    if not left:
        return
    _leaked[:] = [process_tree.describe(pid) for pid in left]
    process_tree.kill_all(left)
    if session.exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if _leaked:
        terminalreporter.section("processes left behind by the test session", red=True)
        for line in _leaked:
            terminalreporter.line(line)
        terminalreporter.line(
            f"{len(_leaked)} process(es) outlived every fixture (killed now); "
            "stop each pool and server a test starts"
        )
