"""The algorithm core of gridplace: a scikit-learn style library with no web, queue or
registry dependency.

>>> from service.encoding import PhaseEncoder
>>> model = PhaseEncoder(n_patterns=2, rho=0.5).fit(reference)   # rows in route order
>>> model.predict(queries)                                        # frame indices
"""

from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter, adapt_drive
from service.encoding.artifacts import (
    check_new_artifact_dir,
    load_model,
    read_manifest,
    save_model,
)
from service.encoding.base import Localization, PlaceRecognizer, precision_at
from service.encoding.baselines import ExactNN, RhythmicEncoder
from service.encoding.calibration import calibrate
from service.encoding.chunked import ChunkedPlaceEncoder
from service.encoding.encoder import PhaseEncoder
from service.encoding.factory import ModelParams, build_model, default_trainer
from service.encoding.footprint import Footprint
from service.encoding.phases import auto_periods, index_to_labels, labels_to_index
from service.encoding.pq import PQIndex, faiss_available
from service.encoding.presets import DEFAULT_PRESET, PRESETS
from service.encoding.route_checks import check_route
from service.encoding.validation import check_descriptors
from service.npyfile import load_npy

__all__ = [
    "DEFAULT_PRESET",
    "PRESETS",
    "AdaptationConfig",
    "AppearanceAdapter",
    "ChunkedPlaceEncoder",
    "ExactNN",
    "Footprint",
    "Localization",
    "ModelParams",
    "PQIndex",
    "PhaseEncoder",
    "PlaceRecognizer",
    "RhythmicEncoder",
    "adapt_drive",
    "auto_periods",
    "build_model",
    "calibrate",
    "check_descriptors",
    "check_new_artifact_dir",
    "check_route",
    "default_trainer",
    "faiss_available",
    "index_to_labels",
    "labels_to_index",
    "load_model",
    "load_npy",
    "precision_at",
    "read_manifest",
    "save_model",
]
