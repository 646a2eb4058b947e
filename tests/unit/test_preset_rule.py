"""Which preset training parameters start from (``presets.base_preset``), and that the
parameters a job or version stores mean the same when they are read back."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import ModelParams
from service.encoding.presets import DEFAULT_PRESET, PAPER_OPTIONS, PRESETS, base_preset
from service.wire.training import TrainingOptions

PAPER_VALUES: dict[str, Any] = {"n_patterns": 3, "periods": (20, 20), "rho": 0.4, "gamma": 2.0,
                                "C": 1.0}  # fmt: skip
NEUTRAL_VALUES: dict[str, Any] = {"n_components": 64, "dtype": "float32", "n_chunks": 2,
                                  "top_chunks": 1, "whiten_power": 0.5, "random_state": 3}  # fmt: skip


@pytest.mark.parametrize("field", PAPER_OPTIONS)
def test_each_option_of_the_paper_code_alone_starts_from_paper(field: str) -> None:
    params = ModelParams(**{field: PAPER_VALUES[field]})
    assert params.encoder_preset == "paper" and params.trainer == "logreg"
    assert params.code == "mixed_radix" and params.n_components is None
    assert base_preset({field: PAPER_VALUES[field]}) == ("paper", (field,))


@pytest.mark.parametrize("trainer", ["logreg", "svm", "ridge", "torch"])
def test_another_trainer_is_the_paper_code_with_it(trainer: str) -> None:
    params = ModelParams(trainer=trainer)  # type: ignore[arg-type]
    named = PRESETS["paper"].params() | {"trainer": trainer}
    for key, value in named.items():
        assert getattr(params, key) == value, key
    assert ModelParams(trainer="ridge").model_dump(exclude={"encoder_preset"}) == ModelParams(
        encoder_preset="ridge").model_dump(exclude={"encoder_preset"})  # fmt: skip


def test_the_default_trainer_and_code_keep_the_default() -> None:
    assert ModelParams(trainer="prototype").encoder_preset == DEFAULT_PRESET
    assert ModelParams(code="residue").encoder_preset == DEFAULT_PRESET
    assert ModelParams(code="mixed_radix").encoder_preset == "paper"
    assert ModelParams().encoder_preset == DEFAULT_PRESET


@given(st.dictionaries(st.sampled_from(sorted(NEUTRAL_VALUES)), st.just(None), max_size=6))
def test_options_the_default_uses_too_keep_the_default(keys: dict[str, None]) -> None:
    chosen = {k: NEUTRAL_VALUES[k] for k in keys}
    params = ModelParams(**chosen)
    assert params.encoder_preset == DEFAULT_PRESET
    for key, value in chosen.items():
        assert getattr(params, key) == value


@settings(max_examples=60, deadline=None)
@given(
    preset=st.one_of(st.none(), st.sampled_from(sorted(PRESETS))),
    paper=st.dictionaries(st.sampled_from(sorted(PAPER_VALUES)), st.just(None), max_size=3),
    neutral=st.dictionaries(st.sampled_from(sorted(NEUTRAL_VALUES)), st.just(None), max_size=3),
)
def test_a_named_preset_wins_and_stored_parameters_read_back_the_same(
    preset: str | None, paper: dict[str, None], neutral: dict[str, None]
) -> None:
    given_ = {**{k: PAPER_VALUES[k] for k in paper}, **{k: NEUTRAL_VALUES[k] for k in neutral}}
    if "periods" in given_:
        given_["n_chunks"] = 1  # periods cover the whole route, not a chunk
    params = ModelParams(encoder_preset=preset, **given_)  # type: ignore[arg-type]
    want = preset or ("paper" if paper else DEFAULT_PRESET)
    assert params.encoder_preset == want
    for key, value in given_.items():
        assert getattr(params, key) == value, key
    # a job's stored parameters (JSON) and a REST upload's fields mean the same model
    assert ModelParams(**params.model_dump(mode="json")) == params
    form = TrainingOptions(**{k: v for k, v in params.model_dump(mode="json").items()
                              if k in TrainingOptions.model_fields})  # fmt: skip
    assert ModelParams(**form.training_params()).encoder_preset == want
