"""Session-wide rules of the test suite (see ``process_guard.py``): no process left behind."""

from process_guard import pytest_configure, pytest_sessionfinish, pytest_terminal_summary

__all__ = ["pytest_configure", "pytest_sessionfinish", "pytest_terminal_summary"]
