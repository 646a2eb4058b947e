"""Fit progress (per class of every digit), the default trainer, and the artifact path check
that runs before a fit. Routes are SYNTHETIC (smooth random process)."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from service.encoding import (
    ChunkedPlaceEncoder,
    ModelParams,
    PhaseEncoder,
    check_new_artifact_dir,
    default_trainer,
    save_model,
)
from service.encoding.presets import DEFAULT_PRESET, preset
from service.encoding.progress import Steps
from service.encoding.synthetic import smooth_route
from service.errors import ConflictError, InvalidInputError, NotFittedError

Report = tuple[str, int, int]


@pytest.fixture(scope="module")
def X() -> np.ndarray:
    return smooth_route(240, 16, seed=3).reference


def _recorder() -> tuple[list[Report], object]:
    seen: list[Report] = []
    return seen, lambda detail, done, total: seen.append((detail, done, total))


def _assert_well_formed(seen: list[Report], total: int) -> None:
    assert seen, "no progress was reported"
    assert {t for _, _, t in seen} == {total}
    done = [d for _, d, _ in seen]
    assert done == sorted(done) and done[0] >= 0 and done[-1] == total


def test_logreg_reports_every_class_of_every_digit(X: np.ndarray) -> None:
    seen, report = _recorder()
    model = PhaseEncoder(trainer="logreg", n_patterns=2).fit(X, progress=report)
    total = sum(model.periods_)
    _assert_well_formed(seen, total)
    per_class = [s for s in seen if s[0].endswith("classes")]
    assert len(per_class) == total  # one report per one-vs-rest problem
    tau1 = model.periods_[0]
    assert (f"digit 1/2: 3/{tau1} classes", 3, total) in seen
    assert seen[-1][0] == f"digit 2/2: {model.periods_[1]}/{model.periods_[1]} classes"


def test_threaded_one_vs_rest_reports_stay_monotone(X: np.ndarray) -> None:
    seen, report = _recorder()
    model = PhaseEncoder(trainer="logreg", n_patterns=2, n_jobs=2).fit(X, progress=report)
    _assert_well_formed(seen, sum(model.periods_))


@pytest.mark.parametrize("trainer", ["ridge", "torch"])
def test_whole_digit_trainers_report_each_digit(X: np.ndarray, trainer: str) -> None:
    seen, report = _recorder()
    model = PhaseEncoder(trainer=trainer, n_patterns=3).fit(X, progress=report)
    _assert_well_formed(seen, sum(model.periods_))
    offsets = np.cumsum((0, *model.periods_))
    assert [d for detail, d, _ in seen if detail.endswith("classes")] == list(offsets[1:])


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_chunked_fit_counts_the_classifier_and_every_chunk(X: np.ndarray, n_jobs: int) -> None:
    seen, report = _recorder()
    model = ChunkedPlaceEncoder(n_chunks=3, trainer="logreg", n_jobs=n_jobs).fit(X, progress=report)
    total = 3 + sum(sum(enc.periods_) for enc in model.chunk_encoders_)
    _assert_well_formed(seen, total)
    assert any(d.startswith("chunk classifier") for d, _, _ in seen)
    if n_jobs == 1:  # in-process chunks report per class
        assert any(d.startswith("chunk 3/3: digit 2/2:") for d, _, _ in seen)
    else:  # child processes: per chunk
        assert [d for d, _, _ in seen if d.endswith(" done")] == [
            "chunk 1/3 done", "chunk 2/3 done", "chunk 3/3 done",
        ]  # fmt: skip


def test_a_raising_callback_aborts_the_fit(X: np.ndarray) -> None:
    class Stop(Exception):
        pass

    def stop_after_five(detail: str, done: int, total: int) -> None:
        if done >= 5:
            raise Stop

    model = PhaseEncoder(trainer="logreg")
    with pytest.raises(Stop):
        model.fit(X, progress=stop_after_five)
    with pytest.raises(NotFittedError):
        model.predict(X[:2])


def test_steps_scale_sub_progress_into_their_budget() -> None:
    seen, report = _recorder()
    steps = Steps(report, ["a", "b"], [10, 30])
    step = steps.step(0)
    assert step is not None
    step(1, 2)
    steps.done(0)
    sub = steps.scope(1)
    assert sub is not None
    sub("x", 1, 3)
    sub("", 3, 3)
    steps.done(1)  # already reported by the sub-fit: not repeated
    assert seen == [("a", 0, 40), ("a: 1/2 classes", 5, 40), ("a done", 10, 40),
                    ("b: x", 20, 40), ("b", 40, 40)]  # fmt: skip
    assert Steps(None, ["a"], [3]).step(0) is None


def test_steps_never_move_backwards_under_concurrent_reports() -> None:
    seen, report = _recorder()
    steps = Steps(report, ["d"], [1000])
    step = steps.step(0)
    assert step is not None

    def work(start: int) -> None:
        for i in range(start, 1000, 4):
            step(i + 1, 1000)

    threads = [threading.Thread(target=work, args=(s,)) for s in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    done = [d for _, d, _ in seen]
    assert done == sorted(done) and done[-1] == 1000


def test_default_trainer_is_the_default_presets() -> None:
    assert default_trainer() == preset(DEFAULT_PRESET).trainer == "prototype"
    assert ModelParams().trainer == default_trainer()
    assert ModelParams(trainer="logreg").trainer == "logreg"  # the paper's, by name
    paper = ModelParams(encoder_preset="paper")
    assert (paper.trainer, paper.code, paper.n_patterns, paper.n_components) == (
        "logreg", "mixed_radix", 2, None)
    assert ModelParams(encoder_preset="paper", trainer="ridge").trainer == "ridge"


def test_artifact_path_check_before_training(tmp_path: Path, X: np.ndarray) -> None:
    assert check_new_artifact_dir(tmp_path / "new" / "model") == tmp_path / "new" / "model"
    (tmp_path / "taken").mkdir()
    with pytest.raises(ConflictError, match="already exists"):
        check_new_artifact_dir(tmp_path / "taken")
    (tmp_path / "file").write_text("x")
    with pytest.raises(InvalidInputError, match="is not a directory"):
        check_new_artifact_dir(tmp_path / "file" / "model")
    with pytest.raises(InvalidInputError, match="not writable"):
        check_new_artifact_dir("/proc/gridplace-model")  # read-only even for root
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "taken"]  # no probe left
    model = PhaseEncoder(trainer="ridge").fit(X)
    with pytest.raises(ConflictError):  # save_model applies the same check
        save_model(model, tmp_path / "taken")
