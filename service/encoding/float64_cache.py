"""Float64 weights kept for re-scoring, within a process-wide byte budget.

A query whose float32 answer cannot be certified is decoded again in float64 with the weights
exactly as the stored model dequantises them. Making those (a cast of the whole ``τ × d'``
block) costs far more than the one product a re-scored query needs, and on real imagery a
tenth of the queries can be near ties. So a digit's float64
weights are kept once made, as long as all kept blocks together stay within
:data:`CACHE_BYTES`; past the budget they are made per call as before (answers are the same
either way: the cast is exact). A block's bytes are returned to the budget when it is freed
(its plan, i.e. its model version, is gone).
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable

import numpy as np

CACHE_BYTES = 256 * 1024 * 1024  # per process, all maps and versions together

_lock = threading.Lock()
_used = 0


def used_bytes() -> int:
    """Bytes of float64 weights kept now."""
    return _used


def _release(nbytes: int) -> None:
    global _used
    with _lock:
        _used -= nbytes


Weights = tuple[np.ndarray, np.ndarray]


def kept(holder: list[Weights], make: Callable[[], Weights]) -> Weights:
    """``holder``'s weights and biases, made by ``make()`` and kept in it if the budget
    allows (``holder`` is an empty list or holds them)."""
    global _used
    if holder:
        return holder[0]
    W, b = make()
    nbytes = W.nbytes + b.nbytes
    with _lock:
        if holder:  # another thread kept them meanwhile
            return holder[0]
        if _used + nbytes > CACHE_BYTES:
            return W, b
        _used += nbytes
        holder.append((W, b))
    weakref.finalize(W, _release, nbytes)
    return W, b
