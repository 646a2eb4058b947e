"""The test environment a fresh machine installs is the tested one: ``requirements/lock.txt``
pins every package the project and its extras need, each pin satisfies ``pyproject.toml``,
and every install command of the README and CI installs through it."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[2]
LOCK = ROOT / "requirements" / "lock.txt"
EXTRAS = ("test", "torch", "faiss")


def _pins() -> dict[str, Version]:
    pins: dict[str, Version] = {}
    for line in LOCK.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        name, sep, version = line.partition("==")
        assert sep and version, f"lock.txt: {line!r} is not an exact pin (name==version)"
        assert "+" not in version, f"lock.txt: {line!r} names a build, not a version"
        pins[canonicalize_name(name)] = Version(version)
    return pins


def _requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = list(project["dependencies"])
    for extra in EXTRAS:
        reqs += project["optional-dependencies"][extra]
    return [Requirement(r) for r in reqs]


def test_every_requirement_is_pinned_within_its_range() -> None:
    pins = _pins()
    assert len(pins) > 40
    for req in _requirements():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} (pyproject.toml) has no pin in requirements/lock.txt"
        assert req.specifier.contains(pins[name], prereleases=True), (
            f"lock.txt pins {req.name}=={pins[name]}, outside pyproject.toml's {req.specifier}"
        )


def test_the_readme_and_ci_install_through_the_lock() -> None:
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    installs = [
        line for text in (readme, ci) for line in text.splitlines()
        if re.search(r"pip install .*-e ", line)
    ]  # fmt: skip
    assert len(installs) >= 3, installs
    for line in installs:
        assert "-c requirements/lock.txt" in line, f"installs without the lock: {line}"
    test_command = "python3 -m pip install -e '.[test,torch,faiss]' -c requirements/lock.txt"
    assert f"{test_command} && python3 -m pytest -q" in readme
    assert f"{test_command} && python3 -m pytest -q" in ci
    assert (ROOT / "requirements" / "refresh-lock").stat().st_mode & 0o111
