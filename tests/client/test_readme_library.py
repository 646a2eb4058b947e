"""The README's library example, run as written on a SYNTHETIC route (the names it leaves to
the reader: ``reference``, ``queries``, ``winter`` and ``idx``)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from service.encoding.synthetic import smooth_route

ROOT = Path(__file__).resolve().parents[2]


def _library_block() -> str:
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## The library") :]
    start = section.index("```python") + len("```python")
    return section[start : section.index("```", start)]


def test_the_readme_library_example_runs_as_written(tmp_path: Path) -> None:
    route = smooth_route(240, 64, query_noise=0.3, seed=5)  # SYNTHETIC
    namespace = {"reference": route.reference, "queries": route.query[:20],
                 "winter": route.query[100:160], "idx": np.arange(100, 160)}  # fmt: skip
    cwd = os.getcwd()
    os.chdir(tmp_path)  # the example saves to "model/"
    try:
        exec(compile(_library_block(), "README.md", "exec"), namespace)  # noqa: S102
    finally:
        os.chdir(cwd)
    model, loc = namespace["model"], namespace["loc"]
    assert loc.index.shape == (20,) and (tmp_path / "model").is_dir()
    assert model.footprint().to_dict()["actual_bytes"] > 0
