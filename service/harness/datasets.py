"""Evaluation datasets: two traversals of one route, from a folder or generated (SYNTHETIC).

Folder layout (what ``gridplace bench paper`` reads)::

    DIR/
      reference/ | reference.npy     first traversal (the route the model is trained on)
      query/     | query.npy         second traversal of the same route
      ground_truth.npy               optional: query i -> reference index (identity if absent)

Each traversal is either a folder of images (grayscale, ordered by file name, all the same
size) or a ``.npy`` matrix (``DIR/reference.npy``, or the single ``.npy`` file inside
``DIR/reference/``). Where both exist the ``.npy`` is preferred (faster, identical content).

Descriptor preprocessing is an explicit, recorded option:

- ``auto``: raw pixels (images, or integer ``.npy`` matrices) get SeqSLAM patch
  normalisation (``patch_normalize`` with ``patch``); float ``.npy`` matrices are taken as
  descriptors unchanged.
- ``patch``: always patch-normalise (the frames must be pixels with a known image shape).
- ``none``: use the values as they are (as float32).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from PIL import Image

from service.encoding.features import patch_normalize
from service.encoding.synthetic import SYNTHETIC_LABEL, smooth_route
from service.errors import InvalidInputError, InvalidParameterError

Preprocess = Literal["auto", "patch", "none"]
PREPROCESS_MODES: tuple[str, ...] = ("auto", "patch", "none")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")


@dataclass(frozen=True)
class Dataset:
    """Reference and query descriptors of one route, with everything needed to label results."""

    name: str
    reference: np.ndarray  # (n_ref, d) float32, rows in route order
    query: np.ndarray  # (n_query, d) float32
    ground_truth: np.ndarray  # (n_query,) int64 reference index of each query
    label: str  # human-readable description that goes into every output
    synthetic: bool
    preprocessing: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    @property
    def n_frames(self) -> int:
        return int(self.reference.shape[0])

    @property
    def n_features(self) -> int:
        return int(self.reference.shape[1])

    def describe(self) -> dict[str, Any]:
        """JSON-ready identity of the dataset (no arrays)."""
        return {
            "name": self.name,
            "label": self.label,
            "synthetic": self.synthetic,
            "N": self.n_frames,
            "n_queries": int(self.query.shape[0]),
            "d": self.n_features,
            "preprocessing": self.preprocessing,
            "source": self.source,
        }

    def segment(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The central ``n`` reference frames, and the queries whose place lies among them.

        Central rather than leading frames, so that quirks at the ends of a route (Nordland
        starts with black frames that no method can tell apart) weigh no more in a short
        sub-route than in the whole one. Returns ``(reference, queries, ground_truth)`` with
        the ground truth relative to the segment.
        """
        if not 2 <= n <= self.n_frames:
            raise InvalidParameterError(f"segment length {n} outside [2, {self.n_frames}]")
        start = (self.n_frames - n) // 2
        keep = (self.ground_truth >= start) & (self.ground_truth < start + n)
        return (
            self.reference[start : start + n],
            self.query[keep],
            self.ground_truth[keep] - start,
        )


def regional_component(n_frames: int, n_features: int, region_length: int, seed: int) -> np.ndarray:
    """A slowly varying, unit-variance SYNTHETIC signal: random anchors every ``region_length``
    frames, linearly interpolated — the scenery of a region changing along a long route."""
    rng = np.random.default_rng(seed)
    anchors = rng.standard_normal((n_frames // region_length + 2, n_features))
    pos = np.arange(n_frames) / region_length
    i0 = pos.astype(np.int64)
    w = (pos - i0)[:, None]
    slow = anchors[i0] * (1.0 - w) + anchors[i0 + 1] * w
    slow /= slow.std(axis=0, keepdims=True) + 1e-12
    return slow


def synthetic_dataset(
    n_frames: int = 2000,
    n_features: int = 512,
    query_noise: float = 0.6,
    smoothness: float = 3.0,
    region_length: int = 0,
    seed: int = 0,
) -> Dataset:
    """A SYNTHETIC route (``service.encoding.synthetic.smooth_route``), clearly labelled.

    ``region_length > 0`` adds :func:`regional_component` to reference and queries alike, so
    that distant parts of a long route differ systematically, as real scenery does (without
    it a long smooth random route has no structure a chunk classifier could learn).
    """
    route = smooth_route(
        n_frames, n_features, smoothness=smoothness, query_noise=query_noise, seed=seed
    )
    ref, qry = route.reference, route.query
    if region_length > 0:
        slow = regional_component(n_frames, n_features, region_length, seed + 1)
        ref = (ref + slow).astype(np.float32)
        qry = (qry + slow).astype(np.float32)
    params = {"n_frames": n_frames, "n_features": n_features, "query_noise": query_noise,
              "smoothness": smoothness, "region_length": region_length, "seed": seed}  # fmt: skip
    region = f", regional component every {region_length} frames" if region_length > 0 else ""
    return Dataset(
        name=f"synthetic-{n_frames}x{n_features}",
        reference=ref,
        query=qry,
        ground_truth=np.arange(n_frames, dtype=np.int64),
        label=f"{SYNTHETIC_LABEL}: N={n_frames}, d={n_features}, query noise {query_noise}{region}",
        synthetic=True,
        preprocessing={"mode": "none", "generator": "smooth_route", **params},
        source="generated",
    )


def load_dataset(
    root: Path | str,
    preprocess: str = "auto",
    patch: int = 16,
    image_shape: tuple[int, int] | None = None,
) -> Dataset:
    """Load ``root`` in the folder format above and preprocess it as recorded."""
    root = Path(root)
    if preprocess not in PREPROCESS_MODES:
        raise InvalidParameterError(
            f"unknown preprocessing {preprocess!r}; choose one of {PREPROCESS_MODES}"
        )
    if not root.is_dir():
        raise InvalidInputError(f"dataset folder {root} does not exist")
    ref_raw, ref_from, ref_shape = _load_traversal(root, "reference")
    qry_raw, qry_from, qry_shape = _load_traversal(root, "query")
    shape = image_shape or ref_shape or qry_shape
    ref, info = _preprocess(ref_raw, preprocess, patch, shape)
    qry, _ = _preprocess(qry_raw, preprocess, patch, shape)
    if ref.shape[1] != qry.shape[1]:
        raise InvalidInputError(
            f"reference descriptors have {ref.shape[1]} columns but queries have {qry.shape[1]}"
        )
    truth = _load_ground_truth(root, qry.shape[0], ref.shape[0])
    info.update({"reference_from": ref_from, "query_from": qry_from,
                 "ground_truth": "ground_truth.npy" if (root / "ground_truth.npy").is_file()
                 else "identity"})  # fmt: skip
    label = (
        f"{root.name}: reference {ref.shape[0]} x query {qry.shape[0]} frames, d={ref.shape[1]}, "
        f"{_describe_preprocessing(info)}"
    )
    return Dataset(
        name=root.name,
        reference=ref,
        query=qry,
        ground_truth=truth,
        label=label,
        synthetic=False,
        preprocessing=info,
        source=str(root.resolve()),
    )


def _describe_preprocessing(info: dict[str, Any]) -> str:
    if info["mode"] == "patch":
        h, w = info["image_shape"]
        return f"{w}x{h} frames, SeqSLAM patch-normalised ({info['patch']}px tiles)"
    return "descriptors used as stored"


def _load_traversal(root: Path, name: str) -> tuple[np.ndarray, str, tuple[int, int] | None]:
    """Raw frames of one traversal, where they came from, and the image shape if known."""
    folder = root / name
    images = _image_files(folder) if folder.is_dir() else []
    shape: tuple[int, int] | None = None
    if images:
        with Image.open(images[0]) as im:
            shape = (im.height, im.width)
    candidates = [root / f"{name}.npy"]
    if folder.is_dir():
        candidates += sorted(folder.glob("*.npy"))
    npys = [c for c in candidates if c.is_file()]
    if npys:
        if len(npys) > 1 and npys[0] != root / f"{name}.npy":
            raise InvalidInputError(f"{folder} holds several .npy files; expected one")
        arr = np.load(npys[0], allow_pickle=False)
        if arr.ndim == 3:
            shape = (int(arr.shape[1]), int(arr.shape[2]))
        elif arr.ndim != 2:
            raise InvalidInputError(f"{npys[0]} must be (n, d) or (n, h, w), got {arr.shape}")
        return arr, str(npys[0].relative_to(root)), shape
    if images:
        return _read_images(images), f"{name}/ ({len(images)} images)", shape
    raise InvalidInputError(
        f"{root} has no {name}.npy and no {name}/ folder with images or a .npy file"
    )


def _image_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def _read_images(files: list[Path]) -> np.ndarray:
    frames = []
    for f in files:
        with Image.open(f) as im:
            frames.append(np.asarray(im.convert("L"), dtype=np.uint8))
    shapes = {fr.shape for fr in frames}
    if len(shapes) != 1:
        raise InvalidInputError(f"images in {files[0].parent} differ in size: {sorted(shapes)}")
    return np.stack(frames)


def _preprocess(
    raw: np.ndarray, mode: str, patch: int, shape: tuple[int, int] | None
) -> tuple[np.ndarray, dict[str, Any]]:
    is_pixels = raw.ndim == 3 or np.issubdtype(raw.dtype, np.integer)
    if mode == "none" or (mode == "auto" and not is_pixels):
        flat = raw.reshape(raw.shape[0], -1).astype(np.float32)
        if not np.isfinite(flat).all():
            raise InvalidInputError("descriptors contain NaN or infinite values")
        return flat, {"mode": "none", "stored_dtype": str(raw.dtype)}
    if shape is None:
        raise InvalidParameterError(
            "patch normalisation needs the image shape: pass image_shape (rows, cols) or keep "
            "the images folder beside the .npy"
        )
    h, w = shape
    if raw.ndim == 2 and raw.shape[1] != h * w:
        raise InvalidInputError(f"rows of {raw.shape[1]} values do not match images of {h}x{w}")
    desc = patch_normalize(raw.reshape(-1, h, w), patch)
    return desc, {"mode": "patch", "patch": patch, "image_shape": [h, w],
                  "stored_dtype": str(raw.dtype)}  # fmt: skip


def _load_ground_truth(root: Path, n_query: int, n_ref: int) -> np.ndarray:
    path = root / "ground_truth.npy"
    if not path.is_file():
        if n_query > n_ref:
            raise InvalidInputError(
                f"{n_query} queries but {n_ref} reference frames and no ground_truth.npy"
            )
        return np.arange(n_query, dtype=np.int64)
    truth = np.load(path, allow_pickle=False)
    if truth.ndim != 1 or truth.shape[0] != n_query:
        raise InvalidInputError(
            f"ground_truth.npy must hold one index per query ({n_query}), got shape {truth.shape}"
        )
    if truth.dtype.kind not in "iu":
        raise InvalidInputError(f"ground_truth.npy must hold integers, got {truth.dtype}")
    if truth.size and (truth.min() < 0 or truth.max() >= n_ref):
        raise InvalidInputError(f"ground_truth.npy indices must lie in [0, {n_ref})")
    return truth.astype(np.int64)
