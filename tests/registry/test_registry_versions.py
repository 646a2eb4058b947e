"""Publishing, listing, activation, rollback, deletion and immutability of versions.
Models are trained on SYNTHETIC routes (see conftest)."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from service.encoding import save_model
from service.errors import ConflictError, InvalidInputError, NotFoundError
from service.registry import Registry, check_version


def test_first_version_auto_activates_later_ones_do_not(registry, publish, model, other_model):
    v1 = publish(model)
    assert (v1.version, v1.active) == (1, True)
    v2 = publish(other_model)
    assert (v2.version, v2.active) == (2, False)
    info = registry.get_map("route-a")
    assert info.active_version == 1
    assert info.versions == [1, 2]
    assert registry.active_version("route-a").version == 1
    assert [v.version for v in registry.list_versions("route-a")] == [1, 2]
    assert [m.name for m in registry.list_maps()] == ["route-a"]


def test_version_info_carries_footprint_metrics_and_checksum(registry, publish, model):
    v = publish(model, extractor={"kind": "patchnorm", "width": 64, "height": 32, "patch": 16})
    assert v.n_frames == 240 and v.n_features == 32 and v.kind == "phase_encoder"
    assert v.footprint["paper_bytes"] > 0 and v.footprint["actual_bytes"] > 0
    assert v.artifact_bytes > 0
    assert len(v.sha256) == 64
    assert v.metrics == {"train_seconds": 0.5}
    assert v.params["trainer"] == "ridge"
    assert v.extractor == {"kind": "patchnorm", "width": 64, "height": 32, "patch": 16}
    assert registry.get_version("route-a", 1) == v


def test_activate_and_roll_back(registry, publish, model, other_model):
    publish(model)
    publish(other_model)
    assert registry.activate("route-a", 2).active
    assert registry.get_version("route-a", 1).active is False
    assert registry.active_version("route-a").version == 2
    registry.activate("route-a", 1)  # rollback
    assert registry.get_map("route-a").active_version == 1
    with pytest.raises(NotFoundError):
        registry.activate("route-a", 7)


def test_delete_active_version_is_a_conflict(registry, publish, model, other_model):
    publish(model)
    publish(other_model)
    with pytest.raises(ConflictError):
        registry.delete_version("route-a", 1)
    registry.delete_version("route-a", 2)
    assert registry.get_map("route-a").versions == [1]
    assert not registry.artifact_dir("route-a", 2).exists()
    with pytest.raises(NotFoundError):
        registry.get_version("route-a", 2)
    with pytest.raises(NotFoundError):
        registry.delete_version("route-a", 2)


def test_version_numbers_are_never_reused(registry, publish, model, other_model):
    publish(model)
    publish(other_model)
    registry.delete_version("route-a", 2)
    assert publish(other_model).version == 3


def test_versions_are_immutable(registry, publish, model, other_model):
    v1 = publish(model)
    before = (registry.artifact_dir("route-a", 1) / "tensors.safetensors").read_bytes()
    publish(other_model)
    assert (registry.artifact_dir("route-a", 1) / "tensors.safetensors").read_bytes() == before
    assert registry.get_version("route-a", 1).sha256 == v1.sha256
    with pytest.raises(ConflictError):  # the artifact store refuses to overwrite
        save_model(other_model, registry.artifact_dir("route-a", 1))
    with pytest.raises(ValidationError):
        v1.version = 5  # type: ignore[misc]


def test_loaded_model_answers_like_the_published_one(registry, publish, model, route):
    publish(model)
    loaded = registry.load_model("route-a", 1)
    np.testing.assert_array_equal(loaded.predict(route.query), model.predict(route.query))


def test_maps_are_independent(registry, publish, model, other_model):
    publish(model, name="a")
    publish(other_model, name="b")
    publish(model, name="b")
    assert {m.name: m.versions for m in registry.list_maps()} == {"a": [1], "b": [1, 2]}


@pytest.mark.parametrize(
    "name", ["", "Route", "../etc", "a/b", "-lead", ".hidden", "x" * 65, "with space", "é"]
)
def test_invalid_map_names_are_rejected(registry, model, name):
    with pytest.raises(InvalidInputError):
        registry.publish(name, model, params={}, extractor=None, metrics={})
    with pytest.raises(InvalidInputError):
        registry.get_map(name)


@pytest.mark.parametrize("version", [0, -1, True, 1.5])
def test_invalid_versions_are_rejected(registry, publish, model, version):
    publish(model)
    with pytest.raises(InvalidInputError):
        registry.get_version("route-a", version)


def test_unknown_map_is_not_found(registry):
    for call in (registry.get_map, registry.list_versions, registry.active_version):
        with pytest.raises(NotFoundError):
            call("nowhere")
    with pytest.raises(NotFoundError):
        registry.get_version("nowhere", 1)


def test_registry_reopens_with_the_same_state(tmp_path, model, other_model):
    reg = Registry(tmp_path)
    reg.publish("m", model, params={}, extractor=None, metrics={})
    reg.publish("m", other_model, params={}, extractor=None, metrics={})
    reg.activate("m", 2)
    again = Registry(tmp_path)
    assert again.get_map("m").active_version == 2
    assert again.generation() == reg.generation()


def test_publishing_a_job_twice_returns_its_one_version(registry, publish, model):
    first = publish(model, job_id="job-1")
    again = publish(model, job_id="job-1")
    assert again.version == first.version
    assert registry.get_map("route-a").versions == [1]
    assert registry.version_for_job("job-1").version == 1


def test_an_unfitted_model_is_refused_before_anything_is_written(registry):
    from service.encoding import PhaseEncoder
    from service.errors import NotFittedError

    with pytest.raises(NotFittedError):
        registry.publish("route-a", PhaseEncoder(), params={}, extractor=None, metrics={})
    with pytest.raises(NotFoundError):
        registry.get_map("route-a")
    assert registry.generation() == 0


def test_deactivate_takes_a_map_out_of_service(registry, publish, model, other_model):
    publish(model)
    gen = registry.generation()
    info = registry.deactivate("route-a")
    assert info.active_version is None and info.versions == [1]
    assert registry.active_version("route-a") is None
    assert registry.generation() > gen
    v2 = publish(other_model)  # not the first version: stays inactive
    assert not v2.active and registry.get_map("route-a").active_version is None
    registry.delete_version("route-a", 1)  # nothing is active, so anything can go
    registry.activate("route-a", 2)
    assert registry.active_version("route-a").version == 2
    with pytest.raises(NotFoundError):
        registry.deactivate("nowhere")


def test_explicit_activation_at_publish(registry, model, other_model):
    kw = {"params": {}, "extractor": None, "metrics": {}}
    assert not registry.publish("m", model, activate=False, **kw).active
    assert registry.get_map("m").active_version is None
    assert registry.publish("m", other_model, activate=True, **kw).active
    assert registry.get_map("m").active_version == 2


def test_an_emptied_map_auto_activates_its_next_version(registry, publish, model, other_model):
    publish(model)
    registry.deactivate("route-a")
    registry.delete_version("route-a", 1)
    assert registry.get_map("route-a").versions == []
    assert publish(other_model).active


def test_version_numbers_outside_sqlite_integers_are_invalid_input(registry: Registry) -> None:
    assert check_version(2**63 - 1) == 2**63 - 1
    for bad in (0, -1, 2**63, 10**30, True, 1.0):
        with pytest.raises(InvalidInputError, match="versions are integers from 1 to"):
            check_version(bad)
        with pytest.raises(InvalidInputError):
            registry.get_version("route-a", bad)  # type: ignore[arg-type]
