"""Admin endpoints (bearer token): upload routes, follow jobs, manage map versions."""

from __future__ import annotations

import functools
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Header, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from pydantic import Field
from pydantic.json_schema import SkipJsonSchema
from starlette.datastructures import FormData, UploadFile

from service.api.auth import require_admin
from service.api.schemas import (
    ADMIN_ERRORS,
    APPEND_FORM,
    ROUTE_FORM,
    MapParam,
    TextParam,
    body_doc,
)
from service.core.appends import append_traversals
from service.core.retrains import retrain_traversals
from service.core.route_submission import submit_route
from service.core.localization import LocalizationService
from service.core.traversal_upload import UploadedFile
from service.errors import RequestValidationError
from service.wire import (
    MAP_NAME_PATTERN,
    MAX_VERSION,
    AppendOptions,
    Job,
    JobPage,
    JobState,
    MapDetail,
    MapSummary,
    TrainingOptions,
    Version,
)

ROUTE_FILE_FIELDS = ("file", "places")

router = APIRouter(prefix="/v1", tags=["admin"], dependencies=[Depends(require_admin)],
                   responses=ADMIN_ERRORS)  # fmt: skip

MapPath = Annotated[str, Path(pattern=MAP_NAME_PATTERN, description="map name")]
VersionPath = Annotated[int, Path(ge=1, le=MAX_VERSION, description="version number")]


def _service(request: Request) -> LocalizationService:
    return request.app.state.context.service  # type: ignore[no-any-return]


def _route_form(form: FormData) -> tuple[list[UploadFile], list[UploadFile], TrainingOptions]:
    """The route files (one per traversal), their place-index files and the training options
    of an upload form (422 naming a bad field)."""
    files = [(k, v) for k, v in form.multi_items() if isinstance(v, UploadFile)]
    extra_files = sorted({k for k, _ in files if k not in ROUTE_FILE_FIELDS})
    if extra_files:
        raise RequestValidationError(f"unexpected file field(s) {', '.join(extra_files)}; "
                                     "send the route as 'file' (once per traversal) and "
                                     "place indices as 'places'", fields=extra_files)  # fmt: skip
    routes = [v for k, v in files if k == "file"]
    places = [v for k, v in files if k == "places"]
    if not routes:
        raise RequestValidationError("file: send the route as one 'file' field per traversal",
                                     field="file")  # fmt: skip
    fields: dict[str, Any] = {}
    for key in {k for k, v in form.multi_items() if isinstance(v, str)}:
        values = form.getlist(key)
        if key != "periods" and len(values) > 1:
            raise RequestValidationError(f"{key}: the field is given {len(values)} times", field=key)
        fields[key] = values if key == "periods" else values[0]
    return routes, places, TrainingOptions.model_validate(fields)


def _append_form(form: FormData) -> tuple[list[UploadFile], list[UploadFile], AppendOptions]:
    """The traversal files, their place-index files and the append options of a form."""
    files = [(k, v) for k, v in form.multi_items() if isinstance(v, UploadFile)]
    extra_files = sorted({k for k, _ in files if k not in ROUTE_FILE_FIELDS})
    if extra_files:
        raise RequestValidationError(f"unexpected file field(s) {', '.join(extra_files)}; "
                                     "send each traversal as 'file' and place indices as "
                                     "'places'", fields=extra_files)  # fmt: skip
    routes = [v for k, v in files if k == "file"]
    if not routes:
        raise RequestValidationError("file: send each traversal as one 'file' field", field="file")
    fields: dict[str, Any] = {}
    for key in {k for k, v in form.multi_items() if isinstance(v, str)}:
        values = form.getlist(key)
        if key != "tag" and len(values) > 1:
            raise RequestValidationError(f"{key}: the field is given {len(values)} times", field=key)
        fields[key] = values if key == "tag" else values[0]
    return routes, [v for k, v in files if k == "places"], AppendOptions.model_validate(fields)


def _uploaded(files: list[UploadFile]) -> list[UploadedFile]:
    return [UploadedFile(f.filename or f"upload {i + 1}", f.file) for i, f in enumerate(files)]


@router.post("/maps/{name}/routes", status_code=202, response_model=Job,
             summary="Upload a route and train a new version",
             openapi_extra=body_doc(None, ROUTE_FORM))  # fmt: skip
async def upload_route(
    request: Request,
    response: Response,
    name: MapPath,
    idempotency_key: Annotated[
        Annotated[str, Field(min_length=1, max_length=200)] | SkipJsonSchema[None],
        Header(alias="Idempotency-Key", description="the same key for the same map returns the same job"),
    ] = None,
) -> Job:
    """A multipart form: the route as ``file`` and any training options; several ``file``
    fields are traversals of the same places (frame-aligned, or with one ``places`` file per
    traversal, in the same order: the int place 0…N−1 of each row). Everything that can
    be checked from the upload itself is checked before the answer: 202 and the queued job
    (poll ``GET /v1/jobs/{id}``). The same ``Idempotency-Key`` for the same map returns the
    existing job instead of a second one; so does the same route (by content) with the same
    parameters and extractor, unless ``force``: then the answer is 200 with ``reused: true``
    (and the job's ``version`` once it succeeded)."""
    async with request.form() as form:
        routes, places, options = _route_form(form)
        job = await run_in_threadpool(
            functools.partial(
                submit_route, _service(request), name, _uploaded(routes),
                options.training_params(), options.extractor_config(), idempotency_key,
                places=_uploaded(places), **options.upload_flags(),
            )
        )  # fmt: skip
    response.headers["Location"] = f"/v1/jobs/{job.id}"
    if job.reused:
        response.status_code = 200
    return Job.model_validate(job)


@router.post("/maps/{name}/versions/{version}/traversals", status_code=201, response_model=Version,
             summary="Append traversals to a version: a new version, without retraining",
             responses={202: {"model": Job, "description": "retrain=true: the training job"}},
             openapi_extra=body_doc(None, APPEND_FORM))  # fmt: skip
async def append(request: Request, response: Response, name: MapPath,
                 version: VersionPath) -> Version | JSONResponse:  # fmt: skip
    """A multipart form: each traversal as ``file`` (descriptors of the version's width, or
    an image archive its extractor reads), optionally one ``places`` file per traversal (the
    place of every row; without one, row ``i`` is place ``i``), condition tags ``tag`` (repeat
    the field: ``season=winter``), ``extend`` (places beyond the route extend it), ``whiten``
    and ``activate``. The version's class means take the new rows, in time proportional to
    them, and the result is published as the map's next immutable version, recording every
    traversal it was built from and its tags (``extra.traversals``); the version appended to
    is unchanged. 409 ``retrain_required`` when an extension needs new periods. With
    ``retrain=true``: 202 with a training job over every traversal of the version and these
    (:mod:`service.core.retrains`) instead."""
    async with request.form() as form:
        routes, places, options = _append_form(form)
        if options.retrain:
            job = await run_in_threadpool(functools.partial(
                retrain_traversals, _service(request), name, version, _uploaded(routes),
                _uploaded(places), options))  # fmt: skip
            return JSONResponse(Job.model_validate(job).model_dump(mode="json"), status_code=202,
                                headers={"Location": f"/v1/jobs/{job.id}"})  # fmt: skip
        info = await run_in_threadpool(functools.partial(
            append_traversals, _service(request), name, version, _uploaded(routes),
            _uploaded(places), options))  # fmt: skip
    response.headers["Location"] = f"/v1/maps/{name}/versions/{info.version}"
    return Version.model_validate(info)


@router.get("/jobs", response_model=JobPage, summary="Training jobs, newest first (paginated)")
def list_jobs(
    request: Request,
    map: Annotated[MapParam, Query(description="only this map's jobs")] = None,  # noqa: A002
    state: Annotated[list[JobState] | SkipJsonSchema[None], Query(
        description="only jobs in these states (repeatable)")] = None,  # fmt: skip
    limit: Annotated[int, Query(ge=1, le=500, description="jobs per page")] = 50,
    cursor: Annotated[TextParam, Query(description="next_cursor of the previous page")] = None,
) -> JobPage:
    jobs, next_cursor = _service(request).list_jobs(map, state, limit, cursor)
    return JobPage(jobs=[Job.model_validate(j) for j in jobs], next_cursor=next_cursor)


@router.get("/jobs/{job_id}", response_model=Job, summary="A training job's state")
def get_job(request: Request, job_id: str) -> Job:
    return Job.model_validate(_service(request).get_job(job_id))


@router.get("/maps", response_model=list[MapSummary], summary="Every map")
def list_maps(request: Request) -> list[MapSummary]:
    return [MapSummary.model_validate(m) for m in _service(request).list_maps()]


@router.get("/maps/{name}", response_model=MapDetail, summary="A map and its active version")
def get_map(request: Request, name: MapPath) -> MapDetail:
    svc = _service(request)
    info = svc.get_map(name)
    active = svc.get_version(name, info.active_version) if info.active_version is not None else None
    loaded = svc.store.get(name)
    return MapDetail.model_validate({
        **MapSummary.model_validate(info).model_dump(), "active": active,
        "serving_version": loaded.version if loaded else None,
    })  # fmt: skip


@router.get("/maps/{name}/versions", response_model=list[Version], summary="A map's versions")
def list_versions(request: Request, name: MapPath) -> list[Version]:
    return [Version.model_validate(v) for v in _service(request).list_versions(name)]


@router.get("/maps/{name}/versions/{version}", response_model=Version, summary="One version")
def get_version(request: Request, name: MapPath, version: VersionPath) -> Version:
    return Version.model_validate(_service(request).get_version(name, version))


@router.post("/maps/{name}/versions/{version}/activate", response_model=Version,
             summary="Activate or roll back to a version (hot swap)")  # fmt: skip
def activate(request: Request, name: MapPath, version: VersionPath) -> Version:
    return Version.model_validate(_service(request).activate(name, version))


@router.post("/maps/{name}/deactivate", response_model=MapSummary,
             summary="Take a map out of service (localize answers 409)")  # fmt: skip
def deactivate(request: Request, name: MapPath) -> MapSummary:
    return MapSummary.model_validate(_service(request).deactivate(name))


@router.delete("/maps/{name}/versions/{version}", status_code=204,
               summary="Delete an inactive version")  # fmt: skip
def delete_version(request: Request, name: MapPath, version: VersionPath) -> Response:
    _service(request).delete_version(name, version)
    return Response(status_code=204)
