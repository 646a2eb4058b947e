"""A training job's scratch directory ``data_dir/jobs/<job_id>/``: intermediate chunk results
shared between the processes (or hosts) that train one route.

Everything is safetensors or a :func:`service.encoding.save_model` artifact — never pickle —
and every file appears atomically (temp file, fsync, rename), so a reader sees a complete
result or none. Only the ``prepare`` step creates the directory; every later write needs it
to exist, so a straggling part of a job that already failed (its workspace removed) cannot
bring it back. A chunk result is written once: a second run of the same chunk (a retry
after its first run finished unrecorded) keeps the first, complete result.
:func:`sweep_workspaces` removes the workspaces of finished or unknown jobs.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load_file, save_file

from service.encoding import load_model, save_model
from service.encoding.appending import ClassTally
from service.encoding.chunked_appending import TALLY_PREFIX
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.encoder import PhaseEncoder
from service.encoding.front_end import FrontEnd
from service.errors import ArtifactError, ConflictError, NotFoundError

if TYPE_CHECKING:
    from service.registry import Registry

log = logging.getLogger(__name__)
PREP = "prep.safetensors"
SWEEP_GRACE_S = 300.0  # a finished job's workspace older than this is an orphan


class JobFinished(ConflictError):
    """The job already ended (failed elsewhere, timed out): this step must not continue."""

    code = "job_finished"


class WorkspaceGone(JobFinished):
    """The job's workspace was removed (the job finished): nothing more is written to it."""
CLASSIFIER = "chunk_classifier.safetensors"


@dataclass(frozen=True)
class Prep:
    """What every chunk job needs: the route-wide front-end (normaliser and projection) and
    the chunk boundaries."""

    normalizer: FrontEnd
    bounds: np.ndarray  # int64 [0, e1, ..., N]

    @property
    def n_chunks(self) -> int:
        return int(self.bounds.shape[0] - 1)


class Workspace:
    def __init__(self, data_dir: Path, job_id: str) -> None:
        self.path = Path(data_dir) / "jobs" / job_id

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)

    def _require(self) -> None:
        if not self.path.is_dir():
            raise WorkspaceGone(f"the workspace of job {self.path.name} was removed (the job "
                                "finished); not writing to it")  # fmt: skip

    # -- preparation ----------------------------------------------------------------------
    def save_prep(self, prep: Prep) -> None:
        arrays = prep.normalizer.to_arrays("norm")
        arrays["bounds"] = np.asarray(prep.bounds, dtype=np.int64)
        self.path.mkdir(parents=True, exist_ok=True)  # the one step that creates it
        self._save_arrays(PREP, arrays)

    def load_prep(self) -> Prep:
        arrays = self._load_arrays(PREP)
        front = FrontEnd.from_arrays(arrays, "norm")
        if front is None:
            raise ArtifactError(f"the preparation of job {self.path.name} stores no normaliser")
        return Prep(front, arrays["bounds"].astype(np.int64))

    # -- chunk classifier -----------------------------------------------------------------
    def save_classifier(self, classifier: DigitClassifier, n_features: int,
                        tally: ClassTally | None = None) -> None:  # fmt: skip
        """The chunk classifier, with its per-chunk counts when it has them (appending)."""
        arrays = classifier.to_arrays("chunk_clf", n_features)
        if tally is not None:
            arrays.update(tally.to_arrays(TALLY_PREFIX))
        self._save_arrays(CLASSIFIER, arrays)

    def load_classifier(self, n_features: int) -> tuple[DigitClassifier, ClassTally | None]:
        arrays = self._load_arrays(CLASSIFIER)
        return (DigitClassifier.from_arrays(arrays, "chunk_clf", n_features),
                ClassTally.from_arrays(arrays, TALLY_PREFIX))  # fmt: skip

    # -- chunk encoders -------------------------------------------------------------------
    def chunk_dir(self, chunk: int) -> Path:
        return self.path / f"chunk-{chunk:05d}"

    def has_chunk(self, chunk: int) -> bool:
        """True if a complete, checksum-valid result of ``chunk`` is there."""
        try:
            self.load_chunk(chunk)
        except ArtifactError:
            return False
        return True

    def save_chunk(self, chunk: int, encoder: PhaseEncoder) -> None:
        """Write ``chunk``'s encoder once (an earlier complete result is kept)."""
        self._require()
        target = self.chunk_dir(chunk)
        if target.exists():
            if self.has_chunk(chunk):
                return
            trash = target.with_name(f".trash-{target.name}-{os.getpid()}")
            os.rename(target, trash)  # an incomplete leftover: replace it
            shutil.rmtree(trash, ignore_errors=True)
        try:
            save_model(encoder, target)
        except ConflictError:  # a concurrent run of this chunk got there first
            if not self.has_chunk(chunk):
                raise

    def load_chunk(self, chunk: int) -> PhaseEncoder:
        model = load_model(self.chunk_dir(chunk))  # sha256-verified
        if not isinstance(model, PhaseEncoder):
            raise ArtifactError(f"chunk {chunk} of job {self.path.name} is not a phase encoder")
        return model

    # -- files ----------------------------------------------------------------------------
    def _save_arrays(self, name: str, arrays: dict[str, np.ndarray]) -> None:
        self._require()
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{name}.", dir=self.path)
        except FileNotFoundError:  # removed just now
            self._require()
            raise
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


def sweep_workspaces(registry: Registry, min_age_s: float = SWEEP_GRACE_S) -> list[Path]:
    """Remove ``jobs/<id>/`` directories of finished or unknown jobs that are ``min_age_s``
    old (left by a straggling part, or by a process that died while cleaning up)."""
    root = registry.data_dir / "jobs"
    removed: list[Path] = []
    if not root.is_dir():
        return removed
    now = time.time()
    for entry in sorted(root.iterdir()):
        try:
            if not entry.is_dir() or now - entry.stat().st_mtime < min_age_s:
                continue
            job = registry.get_job(entry.name)
        except FileNotFoundError:
            continue
        except NotFoundError:
            job = None
        if job is None or job.done:
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
            log.info("removed the orphaned workspace %s", entry)
    return removed
