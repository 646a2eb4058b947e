"""The demo's route: Nordland in ``../shared/data`` through the chosen image extractor, or a
clearly labelled SYNTHETIC route.

The default extractor is the service's default (:data:`service.imaging.DEFAULT_EXTRACTOR`,
the CNN preset that measured best across seasons, ``docs/RESULTS.md``): the demo extracts
the route's PNGs with it exactly as ``gridplace extract`` and image uploads do. Without the
CNN's packages it falls back to ``patchnorm`` and says so.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from service.bench.data import NORDLAND_SHAPE, nordland, shared_data_dir
from service.encoding.synthetic import smooth_route
from service.errors import UnavailableError
from service.imaging import DEFAULT_EXTRACTOR, extract_paths, list_images, make_extractor

NORDLAND_PATCH = 16
EXTRACTORS: tuple[str, ...] = ("default", "cnn", "patchnorm")


@dataclass(frozen=True)
class DemoData:
    reference: np.ndarray
    query: np.ndarray
    label: str
    extractor: dict[str, Any] | None  # how images become these descriptors (None: synthetic)
    query_images: Path | None  # the folder of the query traversal's PNGs (Nordland only)
    extract_seconds: float = 0.0

    def query_image(self, row: int) -> Path | None:
        """The PNG of query row ``row`` (files are named by source frame), if there is one."""
        if self.query_images is None:
            return None
        png = self.query_images / f"images-{(row + 1) * 10:05d}.png"
        return png if png.is_file() else None


def patchnorm_config() -> dict[str, Any]:
    height, width = NORDLAND_SHAPE
    return {"kind": "patchnorm", "width": width, "height": height, "patch": NORDLAND_PATCH}


def _synthetic(frames: int | None, why: str) -> DemoData:
    n = frames or 3000
    synth = smooth_route(n, 512, seed=0)
    label = f"SYNTHETIC smooth random route, {n} frames, d=512 ({why})"
    return DemoData(synth.reference, synth.query, label, None, None)


def _extract(config: dict[str, Any], root: Path, frames: int | None,
             console: Console) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """Both traversals' PNGs through ``config``'s extractor (raises UnavailableError)."""
    ext = make_extractor(config)
    start = time.perf_counter()
    out = []
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  console=console, transient=True) as bar:  # fmt: skip
        for name in ("reference", "query"):
            paths = list_images(root / "nordland-64x32" / name)[:frames]
            task = bar.add_task(f"extracting {name} ({config.get('preset', config['kind'])})",
                                total=len(paths))  # fmt: skip
            out.append(extract_paths(
                ext, paths, lambda done, _n, t=task: bar.update(t, completed=done)
            ))  # fmt: skip
    return out[0], out[1], time.perf_counter() - start


def demo_data(frames: int | None, synthetic: bool, extractor: str, console: Console) -> DemoData:
    """The route for ``gridplace demo`` (see the module docstring)."""
    root = shared_data_dir()
    if synthetic or root is None:
        why = "--synthetic" if synthetic else "no Nordland data in ../shared/data"
        return _synthetic(frames, why)
    config = dict(DEFAULT_EXTRACTOR) if extractor in ("default", "cnn") else patchnorm_config()
    if config["kind"] != "patchnorm":
        try:
            ref, qry, seconds = _extract(config, root, frames, console)
        except UnavailableError as exc:
            console.print(f"[yellow]the CNN extractor is unavailable ({exc}); using patchnorm[/]")
        else:
            label = (f"Nordland summer→winter, {ref.shape[0]} frames, CNN {config.get('preset')} "
                     f"descriptors (d={ref.shape[1]}, extracted in {seconds:.0f}s)")  # fmt: skip
            return DemoData(ref, qry, label, config, root / "nordland-64x32" / "query", seconds)
    route = nordland(limit=frames, patch=NORDLAND_PATCH)
    assert route is not None  # shared_data_dir() found it
    return DemoData(route.reference, route.query, route.label, patchnorm_config(),
                    root / "nordland-64x32" / "query")  # fmt: skip
