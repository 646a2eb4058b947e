"""The route ``gridplace bench drive`` drives: a dataset folder (descriptors, or images
patch-normalised or run through an image extractor), a descriptor pair, or a SYNTHETIC route."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.bench.data import shared_data_dir
from service.bench.quality_bench import descriptor_pair
from service.encoding.synthetic import SYNTHETIC_LABEL, smooth_route
from service.errors import InvalidInputError, InvalidParameterError
from service.harness.datasets import Dataset, load_dataset

SIDES = ("reference", "query")


def synthetic_route(n: int) -> Dataset:
    """A SYNTHETIC route of ``n`` frames (d = 64, noisy queries), labelled as such."""
    if n < 100:
        raise InvalidParameterError("--synthetic needs at least 100 frames")
    r = smooth_route(n, 64, query_noise=1.0, seed=0)
    return Dataset(name="synthetic", reference=r.reference, query=r.query,
                   ground_truth=np.arange(n, dtype=np.int64),
                   label=f"{SYNTHETIC_LABEL}, N = {n}, d = 64, query noise 1.0",
                   synthetic=True, preprocessing={"mode": "none"})  # fmt: skip


def extracted(root: Path, kind: str, work: Path) -> tuple[Path, Path]:
    """``root/reference/`` and ``root/query/`` images through the extractor ``kind`` (as
    ``gridplace extract`` does), written once to ``work`` (a rerun reuses or resumes them)."""
    from service.imaging import extract_folder, list_images, make_extractor, parse_extractor_config
    from service.imaging.settings import ImagingSettings

    ext = make_extractor(parse_extractor_config({"kind": kind}), ImagingSettings())
    outs = []
    for side in SIDES:
        out = work / f"{root.resolve().name}-{kind}-{side}.npy"
        if not out.is_file():
            extract_folder(ext, list_images(root / side), out)
        outs.append(out)
    return outs[0], outs[1]


def load_route(dataset: Path | None, reference: Path | None, query: Path | None,
               ground_truth: Path | None, synthetic: int | None, patch: int = 16,
               name: str | None = None, extractor: str | None = None,
               work: Path | None = None) -> Dataset:  # fmt: skip
    """The one route the options name (see module doc); none: Nordland in the shared data."""
    if sum(x is not None for x in (dataset, reference or query, synthetic)) > 1:
        raise InvalidParameterError("give one of: a dataset folder, --reference/--query, --synthetic")
    if (reference is None) != (query is None):
        raise InvalidParameterError("--reference and --query go together")
    if extractor is not None and dataset is None:
        raise InvalidParameterError("--extractor needs a dataset folder of images")
    if reference is not None and query is not None:
        return descriptor_pair(reference, query, ground_truth, name)
    if synthetic is not None:
        return synthetic_route(synthetic)
    if dataset is None:
        root = shared_data_dir()
        if root is None:
            raise InvalidInputError("no dataset: give a folder, --reference/--query or "
                                    "--synthetic N (Nordland not found in ../shared/data or "
                                    "$GRIDPLACE_SHARED_DATA)")  # fmt: skip
        dataset = root / "nordland-64x32"
    if extractor is not None:
        truth = dataset / "ground_truth.npy"
        ref, qry = extracted(dataset, extractor, work or Path("."))
        return descriptor_pair(ref, qry, ground_truth or (truth if truth.is_file() else None),
                               name or f"{dataset.resolve().name}-{extractor}")  # fmt: skip
    return load_dataset(dataset, preprocess="auto", patch=patch)
