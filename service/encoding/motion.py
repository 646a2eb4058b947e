"""The sequence filter's motion model: how a vehicle's ``(speed, frame)`` state moves between
two query frames.

- **speeds**: a grid ``min_speed … max_speed`` by ``speed_step`` in reference frames per query
  frame (mirrored to negative speeds with ``reverse``), plus a **stopped** state (speed 0) per
  direction when ``stop_probability > 0``. Each frame the speed stays, or with probability
  ``speed_change`` moves to a neighbouring grid speed (a random walk with reflecting ends: the
  vehicle accelerates gradually), and with probability ``speed_jump`` moves to any speed of
  its direction (an abrupt change, or frames the camera dropped); a moving vehicle stops with
  ``stop_probability`` and a stopped one moves on with ``start_probability``, to any speed of
  the direction it was driving in (a vehicle that waits at a light drives on the way it came);
  with ``reverse``, ``direction_change`` flips the sign (and a stopped vehicle's direction).
- **motion**: a state at frame ``i`` with speed ``v`` moves to ``i + v`` (a fractional ``v``
  splits its mass between the two nearest frames). Mass driven off the array's ends leaves it.
- **odometry** (path integration): a frame that comes with a measured displacement ``u``
  (reference frames, signed) moves every state by ``u`` instead, with a Gaussian error of
  standard deviation ``sqrt(odometry_floor² + (odometry_noise·u)²)``; the speed belief is kept
  as it was, so the prior takes over again on frames without odometry.

States are arrays ``(S, …, W)``: speeds first, frames last (the whole route, or windows of it);
every operation is a few array passes, ``O(S·W)``.
"""

from __future__ import annotations

import math

import numpy as np

from service.encoding.sequence_config import SequenceConfig

MAX_ODOMETRY_TAPS = 257  # the odometry error's kernel, frames (σ beyond 32 frames is clipped)


class MotionModel:
    """The speed grid and one prediction step of :class:`SequenceConfig`'s motion prior."""

    def __init__(self, config: SequenceConfig) -> None:
        self.config = config
        v = config.speeds()
        n_dir = v.size // 2 if config.reverse else v.size  # speeds per direction
        # a stopped state per direction, between the two directions' grids: [−, stop−, stop+, +]
        self.stops: list[int] = []
        if config.stop_probability > 0:
            self.stops = [n_dir, n_dir + 1] if config.reverse else [0]
            v = np.insert(v, n_dir if config.reverse else 0, [0.0] * len(self.stops))
        self.speeds = v  # ascending: rows that share the integer part of a speed are contiguous
        first = [0, n_dir + len(self.stops)] if config.reverse else [v.size - n_dir]
        self.blocks = [slice(lo, lo + n_dir) for lo in first]  # each direction's speed grid
        whole = np.floor(v).astype(np.int64)
        frac = (v - whole).astype(np.float32)
        # rows that share the integer part of their speed are shifted by one slice operation
        self.groups = [
            (int(a), slice(int(idx[0]), int(idx[-1]) + 1), frac[idx], bool(frac[idx].any()))
            for a in np.unique(whole)
            for idx in [np.flatnonzero(whole == a)]
        ]

    @property
    def n_states(self) -> int:
        return int(self.speeds.size)

    def predict(
        self, post: np.ndarray, out: np.ndarray, tmp: np.ndarray, scale: float,
        odometry: float | None = None,
    ) -> None:  # fmt: skip
        """``out = scale ·`` the state ``post`` one frame later (``tmp``: scratch of the same
        shape; ``post`` is scratch afterwards)."""
        if odometry is not None:
            self._odometry(post, out, tmp, scale, float(odometry))
            return
        self._change_speed(post, tmp, out, scale)  # tmp = speed-changed state, out scratch
        mixed = tmp
        for a, rows, frac, fractional in self.groups:
            shape = (-1,) + (1,) * (post.ndim - 1)
            if fractional:
                keep = (1 - frac).reshape(shape)
                _shift(out[rows], mixed[rows], a, keep)
                _shift_add(out[rows], mixed[rows], a + 1, frac.reshape(shape), post[rows])
            else:
                _shift(out[rows], mixed[rows], a, None)

    def _odometry(
        self, post: np.ndarray, out: np.ndarray, tmp: np.ndarray, scale: float, u: float
    ) -> None:
        cfg = self.config
        sigma = min(32.0, math.hypot(cfg.odometry_floor, cfg.odometry_noise * u))
        a = math.floor(u)
        f = u - a
        m = round(u)
        delta = u - m  # in [-0.5, 0.5]
        var = sigma * sigma
        if var <= f * (1.0 - f) + 1e-9:  # linear interpolation carries at least that variance
            taps = [(a, 1.0 - f), (a + 1, f)] if f > 0 else [(a, 1.0)]
        elif var + delta * delta <= 0.75:  # three taps with the displacement's mean and variance
            second = var + delta * delta
            taps = [(m - 1, 0.5 * (second - delta)), (m, 1.0 - second), (m + 1, 0.5 * (second + delta))]
        else:  # a Gaussian kernel (its discretisation keeps the variance at these widths)
            lo, hi = math.floor(u - 4 * sigma), math.ceil(u + 4 * sigma)
            k = np.arange(lo, hi + 1)
            w = np.exp(-0.5 * ((k - u) / sigma) ** 2)
            w /= w.sum()
            taps = [(int(s), float(x)) for s, x in zip(k, w, strict=True) if x > 1e-6]
        first = True
        for shift, weight in taps:
            if first:
                _shift(out, post, shift, np.float32(weight * scale))
                first = False
            else:
                _shift_add(out, post, shift, np.float32(weight * scale), tmp)

    def _change_speed(
        self, post: np.ndarray, out: np.ndarray, tmp: np.ndarray, scale: float
    ) -> None:
        """``out = scale ·`` (speed random walk on each direction's grid with reflecting ends,
        stopping and moving on, then direction flips); ``tmp`` is scratch, ``post`` is left as
        it was."""
        cfg = self.config
        q = cfg.speed_change
        np.multiply(post, np.float32(scale * (1.0 - q)), out=out)  # float32 scalars: float32 loops
        h = np.float32(0.5 * q * scale)
        if q > 0:
            np.multiply(post, h, out=tmp)  # each neighbour's share
            for block in self.blocks:
                src, dst = tmp[block], out[block]
                if src.shape[0] > 1:
                    dst[1:] += src[:-1]
                    dst[:-1] += src[1:]
                    dst[0] += src[0]  # reflect: the missing neighbour's share stays
                    dst[-1] += src[-1]
                else:
                    dst += src
                    dst += src
        jump = cfg.speed_jump
        if jump > 0:  # an abrupt change: to any speed of the same direction, evenly
            for block in self.blocks:
                moving = out[block].sum(axis=0)
                out[block] *= np.float32(1.0 - jump)
                out[block] += moving * np.float32(jump / (block.stop - block.start))
        go, halt = cfg.start_probability, cfg.stop_probability
        for stop, block in zip(self.stops, self.blocks, strict=False):  # each direction's stop
            stopped = np.multiply(post[stop], np.float32(scale), out=tmp[stop])
            moving = out[block].sum(axis=0)
            out[block] *= np.float32(1.0 - halt)
            out[block] += stopped * np.float32(go / (block.stop - block.start))
            np.multiply(stopped, np.float32(1.0 - go), out=out[stop])
            out[stop] += moving * np.float32(halt)
        if cfg.reverse:
            r = cfg.direction_change
            np.multiply(out[::-1], np.float32(r), out=tmp)  # v ↔ −v, stop− ↔ stop+: mirrored
            out *= np.float32(1.0 - r)
            out += tmp


def _slices(a: int, n: int) -> tuple[slice, slice]:
    return (slice(a, n), slice(0, n - a)) if a >= 0 else (slice(0, n + a), slice(-a, n))


def _shift(dst: np.ndarray, src: np.ndarray, a: int, w: np.ndarray | np.float32 | None) -> None:
    """``dst[..., i] = w · src[..., i − a]`` (0 where the source lies off the array)."""
    n = src.shape[-1]
    if abs(a) >= n:
        dst.fill(0.0)
        return
    d, s = _slices(a, n)
    if w is None:
        dst[..., d] = src[..., s]
    else:
        np.multiply(src[..., s], w, out=dst[..., d])
    if a >= 0:
        dst[..., :a] = 0.0
    else:
        dst[..., n + a :] = 0.0


def _shift_add(
    dst: np.ndarray, src: np.ndarray, a: int, w: np.ndarray | np.float32, tmp: np.ndarray
) -> None:
    """``dst[..., i] += w · src[..., i − a]`` where the source lies on the array (``tmp``:
    scratch)."""
    n = src.shape[-1]
    if abs(a) >= n:
        return
    d, s = _slices(a, n)
    np.multiply(src[..., s], w, out=tmp[..., d])
    dst[..., d] += tmp[..., d]
