"""A training job's scratch directory ``data_dir/jobs/<job_id>/``: intermediate chunk results
shared between the processes (or hosts) that train one route.

Everything is safetensors or a :func:`service.encoding.save_model` artifact — never pickle —
and every file appears atomically (temp file, fsync, rename), so a reader sees a complete
result or none.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load_file, save_file

from service.encoding import load_model, save_model
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.encoder import PhaseEncoder
from service.encoding.normalization import Normalizer
from service.errors import ArtifactError

PREP = "prep.safetensors"
CLASSIFIER = "chunk_classifier.safetensors"


@dataclass(frozen=True)
class Prep:
    """What every chunk job needs: route-wide normalisation and the chunk boundaries."""

    normalizer: Normalizer
    bounds: np.ndarray  # int64 [0, e1, ..., N]

    @property
    def n_chunks(self) -> int:
        return int(self.bounds.shape[0] - 1)


class Workspace:
    def __init__(self, data_dir: Path, job_id: str) -> None:
        self.path = Path(data_dir) / "jobs" / job_id

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)

    # -- preparation ----------------------------------------------------------------------
    def save_prep(self, prep: Prep) -> None:
        arrays = prep.normalizer.to_arrays("norm")
        arrays["bounds"] = np.asarray(prep.bounds, dtype=np.int64)
        self._save_arrays(PREP, arrays)

    def load_prep(self) -> Prep:
        arrays = self._load_arrays(PREP)
        return Prep(Normalizer.from_arrays(arrays, "norm"), arrays["bounds"].astype(np.int64))

    # -- chunk classifier -----------------------------------------------------------------
    def save_classifier(self, classifier: DigitClassifier, n_features: int) -> None:
        self._save_arrays(CLASSIFIER, classifier.to_arrays("chunk_clf", n_features))

    def load_classifier(self, n_features: int) -> DigitClassifier:
        return DigitClassifier.from_arrays(self._load_arrays(CLASSIFIER), "chunk_clf", n_features)

    # -- chunk encoders -------------------------------------------------------------------
    def chunk_dir(self, chunk: int) -> Path:
        return self.path / f"chunk-{chunk:05d}"

    def save_chunk(self, chunk: int, encoder: PhaseEncoder) -> None:
        target = self.chunk_dir(chunk)
        if target.exists():  # a retried chunk job replaces its earlier result
            shutil.rmtree(target)
        save_model(encoder, target)

    def load_chunk(self, chunk: int) -> PhaseEncoder:
        model = load_model(self.chunk_dir(chunk))  # sha256-verified
        if not isinstance(model, PhaseEncoder):
            raise ArtifactError(f"chunk {chunk} of job {self.path.name} is not a phase encoder")
        return model

    # -- files ----------------------------------------------------------------------------
    def _save_arrays(self, name: str, arrays: dict[str, np.ndarray]) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.", dir=self.path)
        os.close(fd)
        try:
            save_file({k: np.ascontiguousarray(v) for k, v in arrays.items()}, tmp)
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
            os.replace(tmp, self.path / name)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def _load_arrays(self, name: str) -> dict[str, np.ndarray]:
        path = self.path / name
        try:
            return load_file(str(path))
        except FileNotFoundError as exc:
            raise ArtifactError(f"job file {path} is missing (was the job cleaned up?)") from exc
        except (SafetensorError, OSError) as exc:
            raise ArtifactError(f"job file {path} is unreadable: {exc}") from exc
