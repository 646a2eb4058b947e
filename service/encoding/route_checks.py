"""What training parameters require of a route, checked before any training starts.

``fit`` refuses the same things, but only once it runs: a service calls :func:`check_route`
with the route's shape (read from a ``.npy`` header, or an archive's image count and the
extractor's width) to refuse an upload before it queues the job.
"""

from __future__ import annotations

import importlib.util
import math

from service.encoding.chunk_training import plan_chunks
from service.encoding.factory import ModelParams
from service.encoding.patterns import n_selected
from service.encoding.phases import auto_periods, validate_periods
from service.encoding.residue import residue_periods, validate_residue_periods
from service.errors import InvalidParameterError


def check_route(params: ModelParams, n_frames: int, n_features: int) -> None:
    """Raise :class:`InvalidParameterError` now for what fitting ``params`` on an
    ``n_frames × n_features`` route would refuse (or waste storage on), so a service can refuse
    an upload before it queues the training."""
    if n_frames < 2 * params.n_chunks:
        raise InvalidParameterError(
            f"n_chunks={params.n_chunks} is too many for a {n_frames}-frame route: every chunk "
            "needs at least 2 frames", n_frames=n_frames, n_chunks=params.n_chunks,
        )  # fmt: skip
    bounds = plan_chunks(n_frames, params.n_chunks)
    sizes = [int(e - s) for s, e in zip(bounds[:-1], bounds[1:], strict=True)]
    largest, smallest = max(sizes), min(sizes)
    chunked = params.n_chunks > 1
    where = f"the {largest} frames of a chunk" if chunked else f"{largest} frames"
    n_selected(n_features, params.rho)
    if params.chunk_rho is not None:
        n_selected(n_features, params.chunk_rho)
    if params.trainer == "torch" and importlib.util.find_spec("torch") is None:
        raise InvalidParameterError("trainer 'torch' needs PyTorch, which this server lacks")
    if params.code == "residue":
        for size in {smallest, largest}:
            if params.periods is None:
                residue_periods(size, params.n_patterns, params.code_ratio, params.code_exponent)
            else:
                validate_residue_periods(params.periods, size)
        return
    if params.periods is None:
        auto_periods(smallest, params.n_patterns)  # too many patterns for the route
        return
    periods = validate_periods(params.periods, None if chunked else largest)
    if math.prod(periods) < largest:  # ∏τ must cover every chunk
        raise InvalidParameterError(
            f"the product of periods {periods} is {math.prod(periods)}, smaller than {where}",
            periods=list(periods), n_frames=largest,
        )  # fmt: skip
    if periods[0] > largest:
        raise InvalidParameterError(
            f"period {periods[0]} is longer than {where}: its digit would have classes no "
            "frame uses", periods=list(periods), n_frames=largest,
        )  # fmt: skip
    rest = math.prod(periods[1:])
    if len(periods) > 1 and rest >= smallest:
        raise InvalidParameterError(
            f"periods {periods} have more digits than {smallest} frames need: the last "
            f"{len(periods) - 1} alone cover {rest} frames, so the first digit would never "
            "change", periods=list(periods), n_frames=smallest,
        )  # fmt: skip
