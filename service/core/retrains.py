"""Retraining a version with more traversals, as a job: what an append cannot do.

``POST /v1/maps/{name}/versions/{v}/traversals`` with ``retrain=true`` (``gridplace client
append --retrain``) takes the same form as an append — traversal files, place indices, tags,
``extend`` — and, instead of updating the version's class means, queues a training job over
every traversal version ``v`` was built from plus the new ones, through the normal job path
(202 with the job; its state at ``/v1/jobs/{id}``; the new version published by the job). That
is how a route extended beyond what its code's periods label gets its new periods (an append
answers 409 ``retrain_required``), and how the front-end (column statistics, PCA axes) is
refitted on every traversal.

Every traversal's rows must still be readable: the first version's from its training job's
stored upload (``uploads/``, content addressed, never deleted), each appended one's from the
copy an append keeps beside it (``extra.traversals[i].stored``). A version with a traversal
whose rows are not kept (published without a job, e.g. by the library, or appended before
appends kept their rows) is refused with 409 naming it.

The job trains with the version's parameters (without explicit ``periods`` when the route is
extended: they are chosen for the extended route, as for any upload); its version records
the traversals with their tags (``extra.traversals``, ``extra.retrained_from``), and tagged
traversals leave their condition statistics for queries (:mod:`service.core.query_conditions`).
The rows are gathered once in memory, at most ``GRIDPLACE_MAX_RETRAIN_MB``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from service.core.appends import NewTraversals, keep_rows, read_traversals
from service.core.traversal_upload import UploadedFile, store_traversals
from service.core.uploads import relative_to
from service.encoding import ModelParams
from service.encoding.appending import check_new_places
from service.encoding.conditions import condition_key
from service.encoding.traversals import as_traversals
from service.errors import ConflictError, GridplaceError, PayloadTooLargeError
from service.registry.models import RouteSource, VersionInfo
from service.wire.appends import AppendOptions

if TYPE_CHECKING:
    from service.core.localization import LocalizationService
    from service.registry import JobInfo


@dataclass(frozen=True)
class Part:
    """One stored traversal (or several uploaded together) of a version."""

    rows: np.ndarray  # (n, d), memory-mapped
    places: np.ndarray  # int64 (n,)
    entry: dict[str, Any]  # its lineage entry, with where its rows are kept


def _absolute(path: str, data_dir: Path) -> Path:
    p = Path(path)
    return p if p.is_absolute() else data_dir / p


def stored_parts(service: LocalizationService, base: VersionInfo) -> list[Part]:
    """Every traversal ``base`` was built from, read back from where it is kept."""
    from service.jobs.pipeline import open_places, open_route

    registry, data_dir = service.registry, service.settings.data_dir
    entries = base.extra.get("traversals") or [{
        "version": base.version, "n_traversals": base.n_traversals,
        "content_sha256": base.content_sha256, "places": [0, base.n_frames - 1],
        "tags": dict(base.extra.get("tags") or {}),
    }]  # fmt: skip
    parts: list[Part] = []
    for entry in entries:
        entry = dict(entry)
        stored = entry.get("stored")
        try:
            if stored is None and "version" not in entry:
                raise ConflictError(
                    f"a traversal appended to version {entry.get('appended_to')} of map "
                    f"{base.map!r} keeps no rows to retrain from (appended before appends kept "
                    "them); upload every traversal as a new route instead",
                    appended_to=entry.get("appended_to"),
                )  # fmt: skip
            if stored is None:
                origin = registry.get_version(base.map, int(entry["version"]))
                if origin.job_id is None:
                    raise ConflictError(
                        f"map {base.map!r} version {origin.version} was published without a "
                        "training job, so its traversal's descriptors are not kept; upload every "
                        f"traversal as a new route (POST /v1/maps/{base.map}/routes) instead",
                        version=origin.version,
                    )  # fmt: skip
                spec = registry.get_job_spec(origin.job_id)
                rows = open_route(registry.route_path(spec))
                places = open_places(data_dir, spec, rows.shape[0])
                entry["stored"] = {"rows": spec.route,
                                   "places": None if spec.source is None else spec.source.places}  # fmt: skip
            else:
                rows = open_route(_absolute(stored["rows"], data_dir))
                places = None if stored.get("places") is None else np.load(
                    _absolute(stored["places"], data_dir), allow_pickle=False)  # fmt: skip
        except ConflictError:
            raise
        except (GridplaceError, OSError, ValueError, KeyError) as exc:
            raise ConflictError(
                f"a traversal of map {base.map!r} version {base.version} cannot be read back "
                f"({exc}); upload every traversal as a new route instead", version=base.version,
            ) from exc  # fmt: skip
        idx = np.arange(rows.shape[0], dtype=np.int64) if places is None else np.asarray(places, np.int64)
        parts.append(Part(rows, idx, entry))
    return parts


def retrain_traversals(
    service: LocalizationService, name: str, version: int, files: Sequence[UploadedFile],
    places: Sequence[UploadedFile], options: AppendOptions,
) -> JobInfo:  # fmt: skip
    """Queue the training of a new version of ``name`` from every traversal of ``version``
    and ``files`` (see the module docstring); returns the job (202 semantics)."""
    options.check_retrain()
    new = read_traversals(service, name, version, files, places, options)
    service.backend.check_available()  # Redis down → 503 before any heavy work
    parts = stored_parts(service, new.base)
    n_old = int(new.base.n_frames)
    index = new.index or [np.arange(a.shape[0], dtype=np.int64) for a in new.arrays]
    n_new = check_new_places(np.concatenate(index), n_old, options.extend)
    limit = service.settings.max_retrain_mb * 1024 * 1024
    total = sum(4 * p.rows.size for p in parts) + sum(4 * a.size for a in new.arrays)
    if total > limit:
        raise PayloadTooLargeError(
            f"the traversals to retrain on hold {total} bytes of float32, more than "
            f"GRIDPLACE_MAX_RETRAIN_MB={service.settings.max_retrain_mb}", limit_bytes=limit,
        )  # fmt: skip
    tr = as_traversals([np.asarray(p.rows, np.float32) for p in parts] + new.arrays,
                       places=[p.places for p in parts] + index, keep_dtype=True)  # fmt: skip
    data_dir = service.settings.data_dir
    stored = store_traversals(data_dir, tr, "descriptors")
    lineage, conditions = _lineage(parts, new, keep_rows(data_dir, new.arrays, new.index))
    source = RouteSource(
        content_sha256=stored.content_sha256, n_frames=stored.n_places,
        n_features=stored.n_features, n_traversals=stored.n_traversals,
        places=None if stored.places is None else relative_to(stored.places, data_dir),
        conditions=conditions, lineage=lineage, retrained_from=version,
    )  # fmt: skip
    params = dict(new.base.params)
    if n_new > n_old:
        params.pop("periods", None)  # chosen for the extended route, as for any upload
    job = service.backend.submit(name, stored.route, ModelParams.parse(**params),
                                 new.base.extractor, None, source=source)  # fmt: skip
    service.metrics.jobs_submitted.inc()
    return job


def _lineage(parts: list[Part], new: NewTraversals, kept: list[dict[str, str | None]]
             ) -> tuple[list[dict[str, Any]], dict[str, list[list[int]]]]:  # fmt: skip
    """The retrained version's traversals, and the rows of each tagged condition."""
    entries: list[dict[str, Any]] = []
    conditions: dict[str, list[list[int]]] = {}
    offset = 0
    tagged = [(p.entry, p.rows.shape[0]) for p in parts]
    for i, X in enumerate(new.arrays):
        places = new.index[i] if new.index else np.arange(X.shape[0])
        tagged.append(({"rows": int(X.shape[0]), "places": [int(places.min()), int(places.max())],
                        "tags": dict(new.tags), "stored": kept[i],
                        "retrained_from": new.base.version}, X.shape[0]))  # fmt: skip
    for entry, n in tagged:
        key = condition_key(entry.get("tags") or {})
        if key is not None:
            conditions.setdefault(key, []).append([offset, offset + int(n)])
        offset += int(n)
        entries.append(entry)
    return entries, conditions
