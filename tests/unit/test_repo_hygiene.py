"""Code, tests and docs describe the product, never its history: no issue numbers."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCANNED = ("service", "tests", "docs", "deploy", "protos", ".ci")
TOP_FILES = ("README.md", "pyproject.toml", "Dockerfile", "docker-compose.yml")
TEXT_SUFFIXES = {".py", ".md", ".toml", ".yml", ".yaml", ".proto", ".txt", ".cfg", ".ini", ".sh", ""}
SKIPPED_DIRS = {"__pycache__", ".git", ".pytest_cache", ".hypothesis", "gen"}
# "issue 4", "issue #4", "#6's results", "(#12)", "the issue's format"
HISTORY = re.compile(
    r"\bissue\s*#?\s*\d|(?<![\w&/#])#\d{1,2}(?:\.\d+)?(?:'s\b|\)|\b(?![0-9a-fA-F]))|\bthe issue'?s\b",
    re.IGNORECASE,
)


def _files() -> list[Path]:
    found = [ROOT / name for name in TOP_FILES if (ROOT / name).is_file()]
    for top in SCANNED:
        for path in (ROOT / top).rglob("*"):
            if (path.is_file() and path.suffix in TEXT_SUFFIXES
                    and not SKIPPED_DIRS.intersection(path.relative_to(ROOT).parts)):  # fmt: skip
                found.append(path)
    return [p for p in found if p != Path(__file__).resolve()]


def test_no_issue_numbers_in_code_tests_or_docs() -> None:
    files = _files()
    assert any(p.name == "README.md" for p in files) and len(files) > 50
    hits = [
        f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
        for path in files
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
        if HISTORY.search(line)
    ]
    assert not hits, "describe the code, not its history:\n" + "\n".join(hits)


def test_the_pattern_catches_history_and_spares_the_rest() -> None:
    for text in ("gRPC (issue #4)", "see issue 11", "#6's results", "fixed (#12)",
                 "the issue's format", "as in #9.2"):  # fmt: skip
        assert HISTORY.search(text), text
    for text in ("color='#4c72b0'", "# 1. storage", "## 2. Training", "x[#]", "&#39;",
                 "a known issue with WAL", "issues show", "channel #000000"):  # fmt: skip
        assert not HISTORY.search(text), text
