"""Artifacts: bit-identical save/load, checksums, schema, atomicity, no pickle."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service.encoding import (
    ChunkedPlaceEncoder,
    ExactNN,
    PhaseEncoder,
    RhythmicEncoder,
    load_model,
    read_manifest,
    save_model,
)
from service.encoding.artifacts import MANIFEST, TENSORS
from service.encoding.quantization import DTYPES
from service.encoding.synthetic import SyntheticRoute, smooth_route
from service.encoding.trainers import TRAINERS
from service.errors import ArtifactError, ConflictError


def assert_same_predictions(a, b, queries: np.ndarray) -> None:
    la, lb = a.localize(queries), b.localize(queries)
    for field in ("index", "confidence", "chunk", "log_score"):
        np.testing.assert_array_equal(getattr(la, field), getattr(lb, field))


@pytest.mark.parametrize("trainer", TRAINERS)
@pytest.mark.parametrize("dtype", DTYPES)
def test_round_trip_is_bit_identical_for_every_trainer_and_dtype(
    trainer: str, dtype: str, tiny_route: SyntheticRoute, tmp_path: Path
) -> None:
    model = PhaseEncoder(trainer=trainer, dtype=dtype, rho=0.5).fit(tiny_route.reference)
    manifest = save_model(model, tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert_same_predictions(model, loaded, tiny_route.query)
    assert manifest["dtype"] == dtype
    assert manifest["params"]["trainer"] == trainer
    assert manifest["n_frames"] == tiny_route.reference.shape[0]
    assert manifest["meta"]["periods"] == list(model.periods_)


@given(
    seed=st.integers(0, 10_000),
    n=st.integers(20, 80),
    d=st.integers(4, 20),
    k=st.integers(1, 3),
    dtype=st.sampled_from(DTYPES),
    decode=st.sampled_from(["joint", "argmax"]),
)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_round_trip_property(
    seed: int, n: int, d: int, k: int, dtype: str, decode: str, tmp_path_factory
) -> None:
    route = smooth_route(n, d, seed=seed)  # SYNTHETIC
    model = PhaseEncoder(n_patterns=k, trainer="ridge", dtype=dtype, decode=decode).fit(
        route.reference
    )
    path = tmp_path_factory.mktemp("art") / "m"
    save_model(model, path)
    assert_same_predictions(model, load_model(path), route.query)


@pytest.mark.parametrize(
    "model",
    [
        ChunkedPlaceEncoder(n_chunks=3, trainer="ridge", dtype="int8"),
        RhythmicEncoder(trainer="ridge", dtype="float16"),
        ExactNN(dtype="float16"),
    ],
    ids=["chunked", "rhythmic", "exact_nn"],
)
def test_round_trip_of_every_model_kind(model, tiny_route: SyntheticRoute, tmp_path: Path) -> None:
    model.fit(tiny_route.reference)
    save_model(model, tmp_path / "m")
    assert_same_predictions(model, load_model(tmp_path / "m"), tiny_route.query)


def test_manifest_describes_the_artifact(tiny_route: SyntheticRoute, tmp_path: Path) -> None:
    model = PhaseEncoder(trainer="ridge").fit(tiny_route.reference)
    save_model(model, tmp_path / "m", extra={"train_seconds": 1.5})
    man = read_manifest(tmp_path / "m")
    assert man["schema_version"] == 1 and man["kind"] == "phase_encoder"
    assert man["extra"] == {"train_seconds": 1.5}
    assert set(man["files"]) == {TENSORS}
    assert man["files"][TENSORS]["bytes"] == (tmp_path / "m" / TENSORS).stat().st_size
    assert man["footprint"]["actual_bytes"] == model.footprint().actual_bytes
    assert not (tmp_path / "m" / TENSORS).read_bytes().startswith(b"\x80")  # not a pickle


def test_artifacts_are_immutable(tiny_route: SyntheticRoute, tmp_path: Path) -> None:
    model = PhaseEncoder(trainer="ridge").fit(tiny_route.reference)
    save_model(model, tmp_path / "m")
    before = (tmp_path / "m" / TENSORS).read_bytes()
    with pytest.raises(ConflictError):
        save_model(model, tmp_path / "m")
    assert (tmp_path / "m" / TENSORS).read_bytes() == before


def test_corrupt_tensor_file_is_detected(tiny_route: SyntheticRoute, tmp_path: Path) -> None:
    save_model(PhaseEncoder(trainer="ridge").fit(tiny_route.reference), tmp_path / "m")
    path = tmp_path / "m" / TENSORS
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(ArtifactError, match="checksum"):
        load_model(tmp_path / "m")


def test_unknown_schema_and_missing_files_are_refused(tiny_route: SyntheticRoute, tmp_path: Path) -> None:
    save_model(PhaseEncoder(trainer="ridge").fit(tiny_route.reference), tmp_path / "m")
    man_path = tmp_path / "m" / MANIFEST
    man = json.loads(man_path.read_text())
    man_path.write_text(json.dumps({**man, "schema_version": 99}))
    with pytest.raises(ArtifactError, match="schema"):
        load_model(tmp_path / "m")
    with pytest.raises(ArtifactError, match="missing"):
        load_model(tmp_path / "nowhere")


def test_failed_save_leaves_nothing_behind(
    tiny_route: SyntheticRoute, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = PhaseEncoder(trainer="ridge").fit(tiny_route.reference)

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("service.encoding.artifacts.fsync_dir", boom)
    with pytest.raises(OSError):
        save_model(model, tmp_path / "m")
    assert list(tmp_path.iterdir()) == []
