"""The sequence filter (recursive Bayes filter over the route) and every model's frame scores.

Drives are SYNTHETIC: frame scores built from a known trajectory, or a smooth random route.
"""

from __future__ import annotations

import sys
import tracemalloc
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.bench.seqslam_reference import SeqSLAMConfig, SeqSLAMFilter, seqslam_sequence
from service.encoding import (
    ChunkedPlaceEncoder,
    ExactNN,
    PhaseEncoder,
    PQIndex,
    RhythmicEncoder,
    faiss_available,
)
from service.encoding.sequence import (
    SequenceConfig,
    SequenceFilter,
    emission_log_likelihood,
    filter_sequence,
    sequence_localize,
)
from service.encoding.synthetic import smooth_route
from service.errors import InvalidInputError, InvalidParameterError

N = 500


def scores_along(
    positions: np.ndarray, n: int = N, width: float = 2.0, noise: float = 0.0, seed: int = 0
) -> np.ndarray:
    """SYNTHETIC frame scores like descriptor similarities: a bump of height 1 at each true
    position over a flat background (plus Gaussian noise of std ``noise``)."""
    frames = np.arange(n)[None, :]
    S = np.exp(-0.5 * ((frames - np.asarray(positions, dtype=float)[:, None]) / width) ** 2)
    if noise:
        S = S + np.random.default_rng(seed).normal(0.0, noise, S.shape)
    return S


def gaussian_log_likelihood(positions: np.ndarray, n: int = N, width: float = 1.0) -> np.ndarray:
    """SYNTHETIC calibrated log-likelihoods ``−(i − p)²/(2w²)`` (for ``emission="raw"``)."""
    frames = np.arange(n)[None, :]
    return -0.5 * ((frames - np.asarray(positions, dtype=float)[:, None]) / width) ** 2


def track(S: np.ndarray, config: SequenceConfig | None = None) -> np.ndarray:
    return filter_sequence(S, config).index


# -- tracking ------------------------------------------------------------------------------
@pytest.mark.parametrize("speed", [1.0, 2.0, 0.75, 1.5, 1.1])
@pytest.mark.parametrize("emission", ["zscore", "raw"])
def test_a_noiseless_drive_is_tracked_exactly_after_a_short_warm_up(
    speed: float, emission: str
) -> None:
    """Exactly at whole speeds; within one frame at fractional ones (where the true frame is
    itself a rounding of ``speed·t``)."""
    truth = np.rint(np.arange(0, 0.8 * N, speed)).astype(np.int64)
    if emission == "raw":
        S, config = (
            gaussian_log_likelihood(truth),
            SequenceConfig(emission="raw", emission_scale=1.0),
        )
    else:
        S, config = scores_along(truth, width=1.0), SequenceConfig()
    err = np.abs(track(S, config)[5:] - truth[5:])
    assert err.max() <= (0 if speed.is_integer() else 1), err.max()


def test_the_speed_estimate_converges_to_the_drive() -> None:
    truth = np.arange(0, N - 1, 1.5)
    got = filter_sequence(scores_along(truth), SequenceConfig(reverse=False, stop_probability=0))
    # away from the route's last frames, where the faster speeds run off the route
    assert abs(got.speed[-100:-20].mean() - 1.5) < 0.05
    assert got.confidence[-1] > 0.9


def test_the_filter_beats_single_frames_on_a_noisy_drive() -> None:
    truth = np.arange(N - 20)
    S = scores_along(truth, width=3.0, noise=1.5, seed=1)  # single frames mostly wrong
    single = np.mean(np.abs(S.argmax(axis=1) - truth) <= 5)
    filtered = np.mean(np.abs(track(S) - truth) <= 5)
    assert single < 0.5 and filtered > 0.9, (single, filtered)


@pytest.mark.parametrize(("tracking", "within"), [(False, 80), (True, 100)])
def test_it_relocalises_after_a_jump(tracking: bool, within: int) -> None:
    """The whole-route filter and the windowed tracker (whose global checks open windows at
    the kidnapped vehicle's place) both find the vehicle again and stay with it."""
    truth = np.concatenate([np.arange(50, 200), np.arange(350, 480)])  # kidnapped at t=150
    S = scores_along(truth, width=3.0, noise=0.5, seed=2)
    est = track(S, SequenceConfig(tracking=tracking))
    assert np.all(np.abs(est[20:150] - truth[20:150]) <= 2)
    after = np.abs(est[150:] - truth[150:]) <= 2
    assert after[-1]
    recovered = after.size - int(np.argmin(after[::-1]))  # with it from here to the end
    assert recovered <= within, recovered


def test_reverse_driving_is_tracked_only_when_allowed() -> None:
    truth = np.arange(N - 10, 100, -1)
    S = scores_along(truth, width=3.0, noise=0.5, seed=3)
    backwards = track(S, SequenceConfig(reverse=True))
    forwards_only = track(S, SequenceConfig(reverse=False, stop_probability=0.0))
    assert np.mean(np.abs(backwards[10:] - truth[10:]) <= 2) > 0.98
    assert np.mean(np.abs(forwards_only[10:] - truth[10:]) <= 2) < 0.9
    got = filter_sequence(S, SequenceConfig(reverse=True))
    assert got.speed[-1] < -0.9  # it knows it drives backwards


def test_a_stopped_state_holds_the_vehicle_where_it_stands() -> None:
    truth = np.concatenate([np.arange(100, 200), np.full(60, 200), np.arange(200, 300)])
    S = scores_along(truth, width=3.0, noise=0.2, seed=4)
    with_stop = SequenceConfig(stop_probability=0.01, reverse=False)
    moving = SequenceConfig(stop_probability=0.0, reverse=False, speed_jump=0.0)
    held, moving_only = (np.abs(track(S, c) - truth) <= 2 for c in (with_stop, moving))
    assert held[100:160].mean() > 0.6 and moving_only[100:160].mean() < 0.1  # during the stop
    assert held[160:].mean() > 0.95 > moving_only[160:].mean()  # and after it
    got = filter_sequence(S, with_stop)
    assert got.speed[150] < 0.2 and abs(got.speed[-1] - 1.0) < 0.1  # stopped, then moving again
    filt = SequenceFilter(N, with_stop)
    moving_states = SequenceFilter(N, moving).speeds.size
    assert filt.speeds[0] == 0.0 and filt.nbytes == 4 * (moving_states + 1) * N  # one more row


def test_a_chunked_model_minus_inf_frames_cannot_veto_the_track() -> None:
    truth = np.arange(N - 10)
    S = scores_along(truth, width=3.0)
    S[200:210, :] = -np.inf  # ten frames whose model consulted the wrong chunk only
    S[200:210, 0:40] = 0.0
    est = track(S)
    assert np.all(np.abs(est[215:] - truth[215:]) <= 1)


def test_the_former_window_filter_is_beaten_on_a_noisy_drive() -> None:
    """The benchmark's reference (the SeqSLAM window filter) helps, the HMM helps more."""
    truth = np.arange(200)
    S = scores_along(truth, n=300, width=3.0, noise=1.5, seed=1)
    single = np.mean(np.abs(S.argmax(axis=1) - truth) <= 5)
    old = np.mean(np.abs(seqslam_sequence(S, SeqSLAMConfig(window=6)).index - truth) <= 5)
    new = np.mean(np.abs(track(S) - truth) <= 5)
    assert single < old < new, (single, old, new)
    one = SeqSLAMFilter(300, SeqSLAMConfig(window=1))
    for row in S[:5]:
        assert one.update(row).index == int(row.argmax())


# -- cost structure: nothing grows with the history ------------------------------------------
def _calls_per_update(filt: SequenceFilter, row: np.ndarray) -> int:
    """Python and C function calls one update makes (numpy ufuncs and reductions included)."""
    count = 0

    def prof(frame: object, event: str, arg: object) -> None:
        nonlocal count
        if event in ("call", "c_call"):
            count += 1

    sys.setprofile(prof)
    try:
        filt.update(row)
    finally:
        sys.setprofile(None)
    return count


def _peak_bytes_per_update(filt: SequenceFilter, row: np.ndarray) -> int:
    tracemalloc.start()
    try:
        filt.update(row)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_cost_per_frame_does_not_grow_with_the_history() -> None:
    truth = np.arange(0, N - 1, 0.5)
    S = scores_along(truth, noise=0.3)
    filt = SequenceFilter(N)
    for row in S[:3]:
        filt.update(row)
    calls_early, peak_early, state = (
        _calls_per_update(filt, S[3]),
        _peak_bytes_per_update(filt, S[4]),
        filt.nbytes,
    )
    for row in S[5:900]:
        filt.update(row)
    assert _calls_per_update(filt, S[900]) == calls_early  # the same operations at t=4 and t=900
    assert _peak_bytes_per_update(filt, S[901]) <= peak_early + 1024
    assert filt.nbytes == state == 4 * filt.speeds.size * N  # the state is the posterior alone


def test_the_old_filter_rescans_its_window_the_new_one_makes_fixed_array_passes() -> None:
    """The window filter's operations grow with its window; the recursive filter makes the
    same operations (whole-array passes over its ``S × N`` state) for any route length."""
    row = scores_along([10.0])[0]
    grow = []
    for window in (2, 8):
        old = SeqSLAMFilter(N, SeqSLAMConfig(window=window))
        for _ in range(window):
            old.update(row)
        grow.append(_calls_per_update(old, row))  # type: ignore[arg-type]
    assert grow[1] > grow[0]
    small, large = SequenceFilter(200), SequenceFilter(5000)
    for f in (small, large):
        f.update(np.zeros(f.n_frames))
    assert _calls_per_update(small, np.zeros(200)) == _calls_per_update(large, np.zeros(5000))


# -- properties ----------------------------------------------------------------------------
# scores on a 0.001 grid: an added constant must not erase their differences in float64
scores = st.integers(-50_000, 50_000).map(lambda k: k / 1000.0)
rows = st.lists(st.one_of(scores, st.just(-np.inf)), min_size=12, max_size=12).filter(
    lambda r: np.isfinite(r).any()
)


@settings(max_examples=60, deadline=None)
@given(
    drive=st.lists(rows, min_size=1, max_size=6),
    reverse=st.booleans(),
    emission=st.sampled_from(["zscore", "raw"]),
    stop=st.sampled_from([0.0, 0.2]),
)
def test_the_posterior_stays_a_distribution(
    drive: list[list[float]], reverse: bool, emission: str, stop: float
) -> None:
    config = SequenceConfig(
        reverse=reverse, emission=emission, min_speed=0.0, stop_probability=stop
    )
    filt = SequenceFilter(12, config)
    for row in drive:
        est = filt.update(np.array(row))
        post = filt.posterior
        assert np.all(post >= 0) and post.sum() == pytest.approx(1.0, abs=1e-5)
        assert filt.state.sum() == pytest.approx(1.0, abs=1e-5)
        assert 0 <= est.index < 12 and 0.0 <= est.confidence <= 1.0
        assert post[est.index] == pytest.approx(post.max(), rel=1e-5)


@settings(max_examples=40, deadline=None)
@given(
    drive=st.lists(rows, min_size=1, max_size=6),
    shift=st.floats(-1e3, 1e3),
    scale=st.floats(0.1, 10.0),
)
def test_invariant_to_a_constant_and_for_zscore_to_a_positive_scale(
    drive: list[list[float]], shift: float, scale: float
) -> None:
    S = np.array(drive)
    for T, config in (
        (S + shift, SequenceConfig(emission="raw")),
        (S * scale + shift, SequenceConfig()),
    ):
        a, b = SequenceFilter(12, config), SequenceFilter(12, config)
        for row, moved in zip(S, T, strict=True):
            ea, eb = a.update(row), b.update(moved)
            np.testing.assert_allclose(b.state, a.state, rtol=1e-3, atol=1e-6)
            top = np.sort(a.posterior)[-2:]
            if top[1] - top[0] > 1e-4:  # a clear best frame is the same frame
                assert ea.index == eb.index


def test_emission_is_zero_at_the_best_frame_and_fills_minus_inf_with_the_worst() -> None:
    L = np.array([-np.inf, 1.0, 3.0, -2.0])
    e = emission_log_likelihood(L, SequenceConfig(emission="raw", emission_scale=2.0))
    np.testing.assert_allclose(e, [-10.0, -4.0, 0.0, -10.0])
    z = emission_log_likelihood(np.full(5, 7.0), SequenceConfig())
    np.testing.assert_array_equal(z, 0.0)  # a flat row carries no evidence


# -- bad input ---------------------------------------------------------------------------------
def test_bad_rows_raise_clear_errors_and_leave_the_state() -> None:
    filt = SequenceFilter(N)
    S = scores_along(np.arange(20.0))
    for row in S[:10]:
        filt.update(row)
    before = filt.state
    for bad, match in (
        (np.zeros(N - 1), "expected 500"),
        (np.full(N, -np.inf), "every frame"),
        (np.r_[np.nan, np.zeros(N - 1)], "NaN"),
        (np.r_[np.inf, np.zeros(N - 1)], r"\+inf"),
        (np.zeros((2, N)), "shape"),
    ):
        with pytest.raises(InvalidInputError, match=match):
            filt.update(bad)
    np.testing.assert_array_equal(filt.state, before)
    assert filt.update(S[10]).frames_used == 11
    filt.reset()
    assert filt.update(S[0]).frames_used == 1


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"max_speed": 0.2}, "below min_speed"),
        ({"speed_step": 0.001}, "more than 64"),
        ({"speed_step": 5e-324}, "more than 64"),
        ({"relocalization": 0.0}, "relocalization"),
        ({"emission_scale": -1.0}, "emission_scale"),
        ({"emission": "softmax"}, "emission"),
        ({"confidence_radius": -1}, "confidence_radius"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_invalid_configurations_are_named(params: dict[str, object], match: str) -> None:
    with pytest.raises(InvalidParameterError, match=match):
        SequenceConfig.parse(**params)


def test_bad_drives_and_routes() -> None:
    with pytest.raises(InvalidInputError, match="shape"):
        filter_sequence(np.zeros((0, 5)))
    with pytest.raises(InvalidParameterError, match="at least one frame"):
        SequenceFilter(0)
    with pytest.raises(InvalidParameterError, match="frame scores"):
        sequence_localize(object(), np.zeros((3, 4)))
    assert SequenceFilter(1).update(np.zeros(1)).index == 0


# -- every model gives frame scores consistent with its answers ------------------------------
@pytest.fixture(scope="module")
def route():
    return smooth_route(320, 32, query_noise=0.6, seed=5)  # SYNTHETIC


MODELS: list[Callable[[], object]] = [
    lambda: PhaseEncoder(trainer="ridge"),
    lambda: ChunkedPlaceEncoder(n_chunks=3, trainer="ridge", beam_width=10_000),
    lambda: ExactNN(),
    lambda: RhythmicEncoder(trainer="ridge"),
]
if faiss_available():
    MODELS.append(lambda: PQIndex(n_subquantizers=4))


@pytest.mark.parametrize("make", MODELS)
def test_every_model_scores_every_frame_and_filters_a_drive(make, route) -> None:
    model = make().fit(route.reference)  # type: ignore[attr-defined]
    S = model.frame_log_scores(route.query)
    assert S.shape == (320, 320) and not np.isnan(S).any()
    np.testing.assert_array_equal(S.argmax(axis=1), model.localize(route.query).index)
    drive = sequence_localize(model, route.query, block=50)  # blocks do not change the answers
    whole = filter_sequence(S)
    np.testing.assert_array_equal(drive.index, whole.index)
    np.testing.assert_array_equal(drive.raw_index, S.argmax(axis=1))
    truth = np.arange(320)
    assert np.mean(np.abs(drive.index - truth) <= 5) >= np.mean(
        np.abs(drive.raw_index - truth) <= 5
    )
