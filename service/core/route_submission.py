"""Uploading a route to train: validate every traversal file as soon as its shape is known,
store the route content-addressed, and queue its training (202 semantics).

``POST /v1/maps/{name}/routes`` (and ``gridplace client upload``) calls
:func:`submit_route`; the job it queues is then followed through
:class:`~service.core.localization.LocalizationService` (``get_job``, ``list_jobs``).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from service.core.traversal_upload import UploadedFile, parse_traversals, store_traversals
from service.core.uploads import relative_to
from service.encoding import ModelParams, check_route
from service.errors import DimensionMismatchError, InvalidInputError
from service.imaging import make_extractor, parse_extractor_config
from service.registry.models import RouteSource
from service.registry.names import check_map_name

if TYPE_CHECKING:
    from service.core.localization import LocalizationService
    from service.registry import JobInfo


def submit_route(
    service: LocalizationService,
    name: str,
    files: Sequence[UploadedFile],
    params: dict[str, Any],
    extractor: dict[str, Any] | None = None,
    idempotency_key: str | None = None,
    *,
    places: Sequence[UploadedFile] = (),
    allow_dimension_change: bool = False,
    force: bool = False,
) -> JobInfo:
    """Validate and store an uploaded route, then queue its training (202 semantics).

    ``files``: one descriptor file (or image archive) per traversal of the route, frame-
    aligned unless ``places`` gives one place-index file per traversal
    (:mod:`service.core.traversal_upload`). A route of another descriptor width than the
    map's active version is refused (409) unless ``allow_dimension_change``. The same
    route with the same parameters and extractor as an earlier upload answers with that
    upload's job (``reused``; its version when it succeeded) instead of training a copy,
    unless ``force``."""
    check_map_name(name)
    if idempotency_key is not None and not 1 <= len(idempotency_key) <= 200:
        raise InvalidInputError("Idempotency-Key must be 1-200 characters")
    model_params = ModelParams.parse(**params)
    service.backend.check_available()  # Redis down → 503 before any heavy work
    config = parse_extractor_config(extractor).model_dump() if extractor else None
    image_config = parse_extractor_config(config)  # the default for image archives
    extractor_once = functools.cache(lambda: make_extractor(config))  # built (checked) once

    def check_width(n_features: int) -> None:
        """What the width decides, before the data is read (npy header, image count)."""
        d = image_config.n_features if config is not None else None  # no network built
        if d is not None and d != n_features:
            raise DimensionMismatchError(
                f"the extractor {image_config.kind} produces d={d} but the uploaded "
                f"descriptors have d={n_features}", expected=d, got=n_features,
            )  # fmt: skip
        service.registry.check_width(name, n_features, allow_dimension_change)

    def check_params(n_places: int, n_features: int) -> None:
        check_route(model_params, n_places, n_features)

    limit = service.settings.max_upload_mb * 1024 * 1024
    tr, source_kind = parse_traversals(files, places, limit, extractor_once, check_width,
                                       check_params, image_config.n_features)  # fmt: skip
    if source_kind == "images" and config is None:
        config = image_config.model_dump()
    data_dir = service.settings.data_dir
    stored = store_traversals(data_dir, tr, source_kind)  # only valid data lands
    places_file = None if stored.places is None else relative_to(stored.places, data_dir)
    source = RouteSource(content_sha256=stored.content_sha256, n_frames=stored.n_places,
                         n_features=stored.n_features,
                         allow_dimension_change=allow_dimension_change,
                         n_traversals=stored.n_traversals, places=places_file)  # fmt: skip
    job = service.backend.submit(name, stored.route, model_params, config, idempotency_key,
                              source=source, force=force)  # fmt: skip
    service.metrics.jobs_submitted.inc()
    return job
