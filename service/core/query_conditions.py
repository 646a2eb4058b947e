"""The condition a query names, in the service layer (REST and gRPC alike).

A map version records the appearance statistics of every condition it was given tagged
traversals in (:mod:`service.encoding.conditions`; ``season=winter`` from an append tagged so).
Every query may name one with ``condition``:

- a recorded condition's key (``season=winter``; tags sorted by key and joined by ``,``), or
  ``reference`` (the route's own statistics): a query that is not part of an adapted drive is
  standardised by that condition's statistics; an adapted drive (a vehicle's queries, a
  sequence, a stream's vehicle) starts its running statistics from them;
- ``auto``: the closest recorded condition is inferred — from the query's own rows (one
  query, a batch, an unadapted sequence), or, for an adapted drive, from its first
  ``GRIDPLACE_CONDITION_FRAMES`` frames (default 8), fixed after them;
- nothing: single queries and batches are answered as sent (the reference), adapted drives
  infer the condition as with ``auto`` when the version records any, else start from the
  reference.

A name the version does not record is refused (400 ``unknown_condition`` naming the known
ones). Answers report the condition used (``condition``). The cost is ``C·d`` per frame for
the ``C`` conditions (at most 64) while inferring, ``d`` to standardise.
"""

from __future__ import annotations

import numpy as np

from service.core.model_store import LoadedModel
from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter
from service.encoding.conditions import AUTO, ConditionSet, condition_set, infer
from service.errors import InvalidInputError

MAX_CONDITION_NAME = 4096


def recorded(loaded: LoadedModel) -> ConditionSet | None:
    """The version's conditions (reference first), ``None`` when it keeps no route statistics."""
    return condition_set(loaded.model)


def _conditions_of(loaded: LoadedModel) -> ConditionSet:
    """The version's conditions for a query that names one (400 when it records none)."""
    conditions = recorded(loaded)
    if conditions is None:
        raise InvalidInputError(
            f"map {loaded.map!r} version {loaded.version} was trained without normalisation "
            "and records no condition statistics; query without a condition", field="condition",
        )  # fmt: skip
    return conditions


def _check_name(name: str) -> None:
    if not name or len(name) > MAX_CONDITION_NAME:
        raise InvalidInputError(f"condition names a recorded condition in 1 to "
                                f"{MAX_CONDITION_NAME} characters", field="condition")  # fmt: skip


def standardise(loaded: LoadedModel, Q: np.ndarray, condition: str | None) -> tuple[np.ndarray, str | None]:
    """Validated rows ``Q`` standardised by the condition named (``auto``: the one closest to
    all of them), and its name; ``condition=None``: ``Q`` as sent and ``None``."""
    if condition is None:
        return Q, None
    _check_name(condition)
    conditions = _conditions_of(loaded)
    i = infer(conditions, Q) if condition == AUTO else conditions.index(condition)
    front = conditions.mean[0], np.sqrt(conditions.var[0])
    return conditions.standardise(i, Q, *front), conditions.names[i]


def start_drive(adapter: AppearanceAdapter, loaded: LoadedModel, condition: str | None,
                frames: int) -> AppearanceAdapter:  # fmt: skip
    """A fresh drive's ``adapter`` started from the condition named (``auto``, or unset on a
    version that records conditions: inferred from the first ``frames`` frames)."""
    if condition is not None:
        _check_name(condition)
    named = condition not in (None, AUTO)
    conditions = _conditions_of(loaded) if named else recorded(loaded)
    if conditions is None or (condition is None and len(conditions) == 1):
        return adapter  # nothing to start from but the route's own statistics
    which = conditions.index(condition) if named else None
    return adapter.start_from(conditions, which, frames)


def new_drive(loaded: LoadedModel, config: AdaptationConfig, condition: str | None,
              frames: int) -> AppearanceAdapter:  # fmt: skip
    """A new adapter of ``loaded``'s model started from ``condition`` (:func:`start_drive`)."""
    return start_drive(AppearanceAdapter.for_model(loaded.model, config), loaded, condition, frames)


def continue_drive(adapter: AppearanceAdapter, loaded: LoadedModel, condition: str | None) -> None:
    """A running drive whose query names ``condition``: a named one different from the
    drive's moves its starting statistics to it (inference stops); ``auto`` or unset leave
    the drive as it is."""
    if condition is None or condition == AUTO:
        return
    _check_name(condition)
    conditions = _conditions_of(loaded)
    i = conditions.index(condition)
    if adapter.conditions is not conditions:
        adapter.conditions = conditions
        adapter.condition = 0
    adapter.use_condition(i)
