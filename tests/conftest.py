"""Session-wide rules of the test suite (see ``process_guard.py``): no process left behind."""

import signal

from process_guard import pytest_configure, pytest_sessionfinish, pytest_terminal_summary

# A suite started in the background by a shell inherits an ignored SIGINT, and every process
# it starts would inherit that too (Ctrl-C tests would then test nothing): restore Python's
# default handler, which children reset to the default action on exec.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

__all__ = ["pytest_configure", "pytest_sessionfinish", "pytest_terminal_summary"]
