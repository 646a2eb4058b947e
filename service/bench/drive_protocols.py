"""Drives for ``gridplace bench drive``: which query frames a vehicle sends, in which order,
and where it really is at each of them.

A drive is cut from the query traversal (the second recording of the route): its ``rows`` are
query rows in driving order, ``truth`` the reference frame of each (the dataset's ground
truth) and ``motion`` what the vehicle's own motion sensing measures from one frame to the
next, in reference frames (``truth[t] − truth[t−1]``; 0 for the first frame; a kidnapped
vehicle's wheels report its usual step, not the jump). Every generator is seeded, and every
drive stays inside one part of the route (``lo ≤ row < hi``, a split).

Protocols:

- ``whole``: the part of the route as recorded, start to end.
- ``short``: many drives of ``length`` frames from random starts (the recorded speed): the
  precision of the estimate after ``L`` frames, ``L = 1 … length``.
- ``speed``: variable speed with stops. Speed profiles (reference frames per query frame, in
  ``[0.5, 2]``) from three generators — ``piecewise`` (constant stretches of random length),
  ``smooth`` (a sum of slow sinusoids) and ``accelerating`` (linear ramps between the slowest
  and the fastest speed) — so that no figure is tuned to one generator; the position is the
  running sum of the speed, rounded to a frame; stops of 5–20 frames (the same query frame
  sent again) are inserted every 60–250 frames.
- ``traffic``: a second, differently parameterised variable-speed generator — city driving:
  cruising speeds of 0.3–3 reference frames per query frame (beyond the filter's default speed
  grid at both ends) changing by linear ramps, and stops of 20–60 frames every 80–300 frames
  that the vehicle brakes into and accelerates out of (5–20 and 10–40 frames), so it creeps
  below 0.5 on the way; a stopped vehicle's frames are near-identical, not equal: the recorded
  frame and noisy copies of it in turn (:data:`COPIES` copies with descriptor noise, made by
  the bench), as a real camera's would be.
- ``kidnap``: a drive at the recorded speed that, after ``before`` frames, jumps to a random
  frame at least ``min_jump`` frames away and drives on ``after`` frames.
- ``reverse``: the part of the route driven backwards.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from service.errors import InvalidParameterError

MIN_SPEED, MAX_SPEED = 0.5, 2.0
STOP_FRAMES = (5, 20)  # a stop repeats one frame this many times (inclusive)
STOP_GAP = (60, 250)  # frames driven between stops
SpeedProfile = Callable[[np.random.Generator, int], np.ndarray]
TRAFFIC_SPEEDS = (0.3, 3.0)  # cruising speeds of the traffic generator
TRAFFIC_STOPS = (20, 60)  # its stops, frames
TRAFFIC_GAP = (80, 300)  # frames driven between its stops
COPIES = 2  # near-identical copies of each query frame that a stopped vehicle sends in turn


@dataclass(frozen=True)
class Drive:
    protocol: str  # whole | short | speed | kidnap | reverse
    name: str
    rows: np.ndarray  # int64 query rows in driving order
    truth: np.ndarray  # int64 reference frame of each row
    motion: np.ndarray  # float64 displacement since the previous frame, reference frames
    event: int = -1  # kidnap: the first frame after the jump (-1: none)

    def __len__(self) -> int:
        return int(self.rows.shape[0])


def true_motion(truth: np.ndarray) -> np.ndarray:
    """Each frame's displacement since the previous one along ``truth`` (reference frames; the
    first frame's is 0), float64."""
    return np.diff(truth, prepend=truth[:1]).astype(np.float64)


def make_drive(protocol: str, name: str, rows: np.ndarray, ground_truth: np.ndarray,
               event: int = -1) -> Drive:  # fmt: skip
    """A drive over query ``rows``; its truth from ``ground_truth`` (query row → reference
    frame) and its motion from the truth, except across a kidnap's jump (``event``), where the
    wheels report the step before it."""
    rows = np.asarray(rows, dtype=np.int64)
    truth = np.asarray(ground_truth, dtype=np.int64)[rows]
    motion = true_motion(truth)
    if event > 0:
        motion[event] = motion[event - 1]
    return Drive(protocol, name, rows, truth, motion, event)


def _check_part(lo: int, hi: int, frames: int) -> None:
    if hi - lo < frames:
        raise InvalidParameterError(
            f"the part [{lo}, {hi}) has {hi - lo} frames; a drive here needs {frames}"
        )


def whole(lo: int, hi: int, ground_truth: np.ndarray) -> list[Drive]:
    return [make_drive("whole", "whole", np.arange(lo, hi), ground_truth)]


def reverse(lo: int, hi: int, ground_truth: np.ndarray) -> list[Drive]:
    return [make_drive("reverse", "reverse", np.arange(hi - 1, lo - 1, -1), ground_truth)]


def short(lo: int, hi: int, ground_truth: np.ndarray, count: int, length: int,
          seed: int) -> list[Drive]:  # fmt: skip
    """``count`` drives of ``length`` frames from random starts in ``[lo, hi − length]``."""
    _check_part(lo, hi, length)
    starts = np.random.default_rng([seed, 1]).integers(lo, hi - length + 1, size=count)
    return [
        make_drive("short", f"short-{k}", np.arange(s, s + length), ground_truth)
        for k, s in enumerate(starts)
    ]


def kidnap(lo: int, hi: int, ground_truth: np.ndarray, count: int, before: int, after: int,
           min_jump: int, seed: int) -> list[Drive]:  # fmt: skip
    """``count`` drives: ``before`` frames from a random start, then a jump at least
    ``min_jump`` frames away (either direction), then ``after`` frames."""
    _check_part(lo, hi, max(before, after) + min_jump + 1)
    rng = np.random.default_rng([seed, 2])
    out = []
    for k in range(count):
        for _ in range(1000):
            s, t = (int(v) for v in rng.integers(lo, [hi - before + 1, hi - after + 1]))
            if abs(t - (s + before)) >= min_jump:
                break
        else:
            raise InvalidParameterError(f"no jump of {min_jump} frames fits in [{lo}, {hi})")
        rows = np.concatenate([np.arange(s, s + before), np.arange(t, t + after)])
        out.append(make_drive("kidnap", f"kidnap-{k}", rows, ground_truth, event=before))
    return out


# -- variable speed ----------------------------------------------------------------------------
def piecewise_speeds(rng: np.random.Generator, n: int) -> np.ndarray:
    """Constant stretches of 30–200 frames, each at a uniform random speed."""
    out = np.empty(n)
    t = 0
    while t < n:
        span = int(rng.integers(30, 201))
        out[t : t + span] = rng.uniform(MIN_SPEED, MAX_SPEED)
        t += span
    return out


def smooth_speeds(rng: np.random.Generator, n: int) -> np.ndarray:
    """A sum of three sinusoids with periods of 100–600 frames, scaled to the speed range."""
    t = np.arange(n)
    wave = sum(np.sin(2 * np.pi * t / rng.uniform(100, 600) + rng.uniform(0, 2 * np.pi))
               for _ in range(3))  # fmt: skip
    wave = (wave - wave.min()) / max(float(np.ptp(wave)), 1e-12)
    return MIN_SPEED + (MAX_SPEED - MIN_SPEED) * wave


def accelerating_speeds(rng: np.random.Generator, n: int) -> np.ndarray:
    """Linear ramps between the slowest and the fastest speed, each over 50–300 frames."""
    out = np.empty(n)
    t, v = 0, float(rng.uniform(MIN_SPEED, MAX_SPEED))
    while t < n:
        span = int(rng.integers(50, 301))
        target = MAX_SPEED if v < 0.5 * (MIN_SPEED + MAX_SPEED) else MIN_SPEED
        out[t : t + span] = np.linspace(v, target, span)[: n - t]
        t, v = t + span, target
    return out


SPEED_PROFILES: dict[str, SpeedProfile] = {
    "piecewise": piecewise_speeds,
    "smooth": smooth_speeds,
    "accelerating": accelerating_speeds,
}


def with_stops(speeds: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``speeds`` with stops (runs of speed 0 of :data:`STOP_FRAMES` frames) every
    :data:`STOP_GAP` frames; the same length."""
    out = speeds.copy()
    t = int(rng.integers(*STOP_GAP))
    while t < out.size:
        stop = int(rng.integers(STOP_FRAMES[0], STOP_FRAMES[1] + 1))
        out[t : t + stop] = 0.0
        t += stop + int(rng.integers(*STOP_GAP))
    return out


def positions(start: int, speeds: np.ndarray, hi: int) -> np.ndarray:
    """Frames visited from ``start``: the first frame is ``start``, then the running sum of
    ``speeds[1:]`` rounded to a frame, cut where it would leave ``[start, hi)``."""
    p = start + np.concatenate([[0.0], np.cumsum(speeds[1:])])
    rows = np.rint(p).astype(np.int64)
    inside = rows < hi
    return rows[: int(np.argmin(inside)) if not inside.all() else rows.size]


def speed(lo: int, hi: int, ground_truth: np.ndarray, count: int, frames: int, seed: int,
          profiles: tuple[str, ...] = tuple(SPEED_PROFILES)) -> list[Drive]:  # fmt: skip
    """``count`` drives per speed profile, each at most ``frames`` query frames with stops,
    from a random start that leaves room for ``frames`` frames at the mean speed."""
    _check_part(lo, hi, 50)
    out = []
    for p, profile in enumerate(profiles):
        if profile not in SPEED_PROFILES:
            raise InvalidParameterError(f"unknown speed profile {profile!r}")
        rng = np.random.default_rng([seed, 3, p])
        for k in range(count):
            v = with_stops(SPEED_PROFILES[profile](rng, frames), rng)
            room = max(lo, hi - int(np.ceil(v.sum())) - 1)
            start = int(rng.integers(lo, room + 1)) if room > lo else lo
            rows = positions(start, v, hi)
            out.append(make_drive("speed", f"speed-{profile}-{k}", rows, ground_truth))
    return out


# -- traffic: a second generator --------------------------------------------------------------
def _ramp(start: float, end: float, frames: int) -> np.ndarray:
    return np.linspace(start, end, frames + 1)[1:]


def traffic_speeds(rng: np.random.Generator, n: int) -> np.ndarray:
    """City driving (see the module doc): cruising at ramped speeds, braking into stops and
    accelerating out of them."""
    parts: list[np.ndarray] = []
    v = float(rng.uniform(*TRAFFIC_SPEEDS))
    total = 0
    while total < n:
        drive = int(rng.integers(*TRAFFIC_GAP))
        while drive > 0:  # cruise: ramps between random speeds
            span = min(drive, int(rng.integers(40, 151)))
            target = float(rng.uniform(*TRAFFIC_SPEEDS))
            ramp = min(span, int(rng.integers(10, 41)))
            parts += [_ramp(v, target, ramp), np.full(span - ramp, target)]
            v, drive = target, drive - span
        brake, stop, go = (int(rng.integers(5, 21)), int(rng.integers(*TRAFFIC_STOPS)),
                           int(rng.integers(10, 41)))  # fmt: skip
        v_next = float(rng.uniform(*TRAFFIC_SPEEDS))
        parts += [_ramp(v, 0.0, brake), np.zeros(stop), _ramp(0.0, v_next, go)]
        v = v_next
        total = sum(p.size for p in parts)
    return np.concatenate(parts)[:n]


def near_identical(rows: np.ndarray, n_rows: int, copies: int = COPIES) -> np.ndarray:
    """``rows`` with each repeat of a frame replaced by its copies in turn: the ``k``-th copy of
    query row ``r`` is row ``r + k·n_rows`` of the bench's extended query rows."""
    out = rows.copy()
    k = 0
    for t in range(1, rows.size):
        k = k + 1 if rows[t] == rows[t - 1] else 0
        out[t] = rows[t] + (k % (copies + 1)) * n_rows
    return out


def traffic(lo: int, hi: int, ground_truth: np.ndarray, count: int, frames: int,
            seed: int, copies: int = COPIES) -> list[Drive]:  # fmt: skip
    """``count`` traffic drives of at most ``frames`` query frames from random starts; their
    rows index the query rows extended by ``copies`` noisy copies (``ground_truth`` is of the
    recorded rows only)."""
    _check_part(lo, hi, 50)
    n_rows = int(np.asarray(ground_truth).shape[0])
    truth = np.tile(np.asarray(ground_truth, dtype=np.int64), copies + 1)
    rng = np.random.default_rng([seed, 5])
    out = []
    for k in range(count):
        v = traffic_speeds(rng, frames)
        room = max(lo, hi - int(np.ceil(v.sum())) - 1)
        start = int(rng.integers(lo, room + 1)) if room > lo else lo
        rows = near_identical(positions(start, v, hi), n_rows, copies)
        out.append(make_drive("traffic", f"traffic-{k}", rows, truth))
    return out


# -- odometry ----------------------------------------------------------------------------------
def noisy_odometry(motion: np.ndarray, level: float, seed: int | Sequence[int]) -> np.ndarray:
    """SIMULATED odometry from the true displacement: ``motion·(1 + level·ε₁) + level·ε₂``
    with ``ε`` standard normal per frame (multiplicative and additive noise, the additive part
    in reference frames); ``level = 0``: exact."""
    if level == 0:
        return motion.astype(np.float64, copy=True)
    rng = np.random.default_rng([*np.atleast_1d(seed).tolist(), 4])
    e1, e2 = rng.standard_normal((2, motion.size))
    return motion * (1.0 + level * e1) + level * e2
