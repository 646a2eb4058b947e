"""Appearance adaptation under outliers, and a fleet's frames adapted in vectorised steps."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from service.encoding.adaptation import (
    AdaptationConfig,
    AppearanceAdapter,
    RouteStatistics,
    transform_rows,
)

RECOVERY_FRAMES = 300  # 6 / alpha at the default alpha
RECOVERY_TOLERANCE = 0.02  # of the route's σ, in every column of every later answer

finite = st.floats(allow_nan=False, allow_infinity=False)


def _route_and_drive(seed: int, d: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Route statistics and a drive of ``n`` frames from another season: every column shifted
    by up to 2 σ and rescaled by 0.5–1.5."""
    rng = np.random.default_rng(seed)
    mu, sigma = rng.normal(size=d), rng.uniform(0.5, 2.0, size=d)
    shift, spread = rng.uniform(-2, 2, size=d), rng.uniform(0.5, 1.5, size=d)
    return mu, sigma, mu + sigma * (shift + spread * rng.normal(size=(n, d)))


@st.composite
def poison_frames(draw: st.DrawFn, base: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Any finite frame: arbitrary values, one value everywhere, or a frame of the drive with
    some columns (or all) moved by any number of σ."""
    d = base.shape[0]
    kind = draw(st.sampled_from(["any", "constant", "moved"]))
    if kind == "any":
        return draw(arrays(np.float64, d, elements=finite))
    if kind == "constant":
        return np.full(d, draw(finite))
    moved = draw(arrays(np.float64, d, elements=st.floats(-1e6, 1e6) | st.just(0.0)))
    with np.errstate(over="ignore"):
        frame = base + moved * sigma
    return np.where(np.isfinite(frame), frame, base)


@settings(max_examples=40, deadline=None)
@given(data=st.data(), seed=st.integers(0, 2**31), d=st.integers(64, 160), at=st.integers(0, 80))
def test_a_drive_recovers_from_any_finite_poison_frame(data: st.DataObject, seed: int, d: int,
                                                       at: int) -> None:  # fmt: skip
    """One wild frame anywhere in a normal drive: the answers to the drive's later frames are,
    within a bounded number of frames, those of the same drive without it (a frame far
    outside the statistics is not learnt from at all; one inside moves them by a bounded
    step that the drive washes out)."""
    n = at + RECOVERY_FRAMES + 100
    mu, sigma, X = _route_and_drive(seed, d, n)
    poison = data.draw(poison_frames(X[at], sigma), label="poison")
    clean = AppearanceAdapter(mu, sigma).transform(X)
    poisoned = AppearanceAdapter(mu, sigma)
    got = poisoned.transform(np.insert(X, at, poison, axis=0))
    later = np.delete(got, at, axis=0)[at + RECOVERY_FRAMES :]
    assert np.all(np.abs(later - clean[at + RECOVERY_FRAMES :]) <= RECOVERY_TOLERANCE * sigma)
    with np.errstate(over="ignore"):
        z2 = np.mean(((poison - X[:at].mean(axis=0) if at else poison - mu) / sigma) ** 2)
    if z2 > 1e4:  # far outside anything the drive could have learnt: not learnt from
        assert np.array_equal(np.delete(got, at, axis=0), clean)
        assert poisoned.outliers == 1


def test_an_all_1e6_frame_changes_no_later_answer() -> None:
    mu, sigma, X = _route_and_drive(7, 512, 200)
    clean = AppearanceAdapter(mu, sigma).transform(X)
    a = AppearanceAdapter(mu, sigma)
    got = a.transform(np.insert(X, 10, np.full(512, 1e6), axis=0))
    assert np.array_equal(np.delete(got, 10, axis=0), clean)
    assert np.all(np.abs(got[10]) > 1e4)  # answered: standardised as any frame is
    assert a.outliers == 1 and a.frames == 201 and a.learnt == 200


def test_a_drive_that_moves_away_for_good_is_learnt_again() -> None:
    """A camera swapped mid-drive (every column 40 σ away): after ``patience`` outlying
    frames the statistics restart from the new drive's frames and standardise it again."""
    mu, sigma, X = _route_and_drive(3, 128, 600)
    moved = X.copy()
    moved[200:] = moved[200:] * 3.0 + 40 * sigma
    a = AppearanceAdapter(mu, sigma)
    out = a.transform(moved)
    assert 8 <= a.outliers <= 12
    z = (out[450:] - mu) / sigma  # the model's z-scores once the new drive is learnt
    assert np.all(np.abs(z.mean(axis=0)) < 0.6) and np.all(np.abs(z.std(axis=0) - 1) < 0.4)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), vehicles=st.integers(1, 6), frames=st.integers(1, 12),
       cuts=st.lists(st.integers(1, 20), min_size=1, max_size=8),
       config=st.sampled_from([AdaptationConfig(), AdaptationConfig(novelty=0.0, alpha=0.3)]))  # fmt: skip
def test_vectorised_steps_equal_each_vehicles_own_drive(seed: int, vehicles: int, frames: int,
                                                        cuts: list[int],
                                                        config: AdaptationConfig) -> None:  # fmt: skip
    """Frames of several vehicles, interleaved in batches of any size (a vehicle may have
    several frames in one batch, and one batch a wild frame): every answer equals the
    vehicle's own adapter fed its own frames in order, bit for bit."""
    rng = np.random.default_rng(seed)
    d = 24
    route = RouteStatistics.of(rng.normal(size=d), rng.uniform(0.5, 2, size=d))
    drives = rng.normal(size=(vehicles, frames, d)) * 1.5 + 0.3
    drives[0, frames // 2] = 1e9  # an outlier among them
    alone = [AppearanceAdapter(route, config=config) for _ in range(vehicles)]
    want = [alone[v].transform(drives[v]) for v in range(vehicles)]
    fleet = [AppearanceAdapter(route, config=config) for _ in range(vehicles)]
    order = [(v, t) for t in range(frames) for v in rng.permutation(vehicles)]  # interleaved
    got = np.empty_like(drives)
    pos, k = 0, 0
    while pos < len(order):
        batch = order[pos : pos + cuts[k % len(cuts)]]
        pos, k = pos + len(batch), k + 1
        rows = transform_rows([fleet[v] for v, _ in batch], [drives[v, t] for v, t in batch])
        for (v, t), row in zip(batch, rows, strict=True):
            got[v, t] = row
    for v in range(vehicles):
        assert np.array_equal(got[v], want[v])
        assert (fleet[v].frames, fleet[v].learnt, fleet[v].outliers) == (
            alone[v].frames, alone[v].learnt, alone[v].outliers)
        assert np.array_equal(fleet[v]._state, alone[v]._state)
