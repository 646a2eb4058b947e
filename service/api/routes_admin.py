"""Admin endpoints (bearer token): upload routes, follow jobs, manage map versions."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, File, Form, Header, Query, Request, Response, UploadFile
from fastapi.concurrency import run_in_threadpool

from service.api.auth import require_admin
from service.api.routes_localize import ERRORS
from service.api.schemas import JobOut, JobPage, MapDetail, MapOut, VersionOut
from service.core.localization import LocalizationService
from service.encoding.phases import parse_periods
from service.registry.names import check_map_name

router = APIRouter(prefix="/v1", tags=["admin"], dependencies=[Depends(require_admin)],
                   responses={**ERRORS, 401: ERRORS[400], 403: ERRORS[400]})  # fmt: skip


def _service(request: Request) -> LocalizationService:
    return request.app.state.context.service  # type: ignore[no-any-return]


Opt = Annotated[int | None, Form()]


@router.post("/maps/{name}/routes", status_code=202, response_model=JobOut,
             summary="Upload a route and train a new version")  # fmt: skip
async def upload_route(
    request: Request,
    response: Response,
    name: str,
    file: Annotated[UploadFile, File(description=".npy/.npz descriptors or .zip/.tar of images")],
    n_patterns: Opt = None,
    periods: Annotated[str | None, Form(description="e.g. 60,60")] = None,
    rho: Annotated[float | None, Form()] = None,
    gamma: Annotated[float | None, Form()] = None,
    trainer: Annotated[str | None, Form(description="logreg | svm | ridge | torch")] = None,
    C: Annotated[float | None, Form()] = None,
    decode: Annotated[str | None, Form(description="joint | argmax")] = None,
    beam_width: Opt = None,
    dtype: Annotated[str | None, Form(description="float64 | float32 | float16 | int8")] = None,
    n_chunks: Opt = None,
    chunk_rho: Annotated[float | None, Form()] = None,
    top_chunks: Opt = None,
    random_state: Opt = None,
    extractor: Annotated[str | None, Form(description="patchnorm | hog | cnn (image archives)")] = None,
    width: Opt = None,
    height: Opt = None,
    patch: Opt = None,
    orientations: Opt = None,
    pixels_per_cell: Opt = None,
    cells_per_block: Opt = None,
    arch: Annotated[str | None, Form()] = None,
    weights: Annotated[str | None, Form(description="server-side path of CNN weights")] = None,
    allow_dimension_change: Annotated[bool, Form(
        description="accept a descriptor width other than the active version's (its clients "
        "must change too); refused with 409 otherwise")] = False,
    force: Annotated[bool, Form(
        description="train even if this route was uploaded before with the same parameters")
    ] = False,
    idempotency_key: Annotated[str | None, Header(alias="Idempotency-Key")] = None,
) -> JobOut:
    """Returns 202 and the training job; poll ``GET /v1/jobs/{id}``. The same
    ``Idempotency-Key`` for the same map returns the existing job instead of a second one;
    so does the same route (by content) with the same parameters and extractor, unless
    ``force``: then the answer is 200 with ``reused: true`` (and the job's ``version`` once
    it succeeded)."""
    check_map_name(name)
    params: dict[str, Any] = {
        k: v for k, v in dict(
            n_patterns=n_patterns, rho=rho, gamma=gamma, trainer=trainer, C=C, decode=decode,
            beam_width=beam_width, dtype=dtype, n_chunks=n_chunks, chunk_rho=chunk_rho,
            top_chunks=top_chunks, random_state=random_state,
        ).items() if v is not None
    }  # fmt: skip
    if periods:
        params["periods"] = parse_periods(periods)
    ext: dict[str, Any] = {
        k: v for k, v in dict(
            width=width, height=height, patch=patch, orientations=orientations,
            pixels_per_cell=pixels_per_cell, cells_per_block=cells_per_block, arch=arch,
            weights=weights,
        ).items() if v is not None
    }  # fmt: skip
    ext_config = {"kind": extractor or "patchnorm", **ext} if (extractor or ext) else None
    job = await run_in_threadpool(
        _service(request).submit_route, name, file.filename or "upload", file.file, params,
        ext_config, idempotency_key, allow_dimension_change=allow_dimension_change, force=force,
    )  # fmt: skip
    response.headers["Location"] = f"/v1/jobs/{job.id}"
    if job.reused:
        response.status_code = 200
    return JobOut.model_validate(job)


@router.get("/jobs", response_model=JobPage, summary="Training jobs, newest first (paginated)")
def list_jobs(
    request: Request,
    map: Annotated[str | None, Query(description="only this map's jobs")] = None,  # noqa: A002
    state: Annotated[list[str] | None, Query(
        description="only jobs in these states (repeatable): queued, running, succeeded, failed"
    )] = None,
    limit: Annotated[int, Query(ge=1, le=500, description="jobs per page")] = 50,
    cursor: Annotated[str | None, Query(description="next_cursor of the previous page")] = None,
) -> JobPage:
    jobs, next_cursor = _service(request).list_jobs(map, state, limit, cursor)
    return JobPage(jobs=[JobOut.model_validate(j) for j in jobs], next_cursor=next_cursor)


@router.get("/jobs/{job_id}", response_model=JobOut, summary="A training job's state")
def get_job(request: Request, job_id: str) -> JobOut:
    return JobOut.model_validate(_service(request).get_job(job_id))


@router.get("/maps", response_model=list[MapOut], summary="Every map")
def list_maps(request: Request) -> list[MapOut]:
    return [MapOut.model_validate(m) for m in _service(request).list_maps()]


@router.get("/maps/{name}", response_model=MapDetail, summary="A map and its active version")
def get_map(request: Request, name: str) -> MapDetail:
    svc = _service(request)
    info = svc.get_map(name)
    detail = MapDetail.model_validate(info)
    if info.active_version is not None:
        detail.active = VersionOut.model_validate(svc.get_version(name, info.active_version))
    loaded = svc.store.get(name)
    detail.serving_version = loaded.version if loaded else None
    return detail


@router.get("/maps/{name}/versions", response_model=list[VersionOut], summary="A map's versions")
def list_versions(request: Request, name: str) -> list[VersionOut]:
    return [VersionOut.model_validate(v) for v in _service(request).list_versions(name)]


@router.get("/maps/{name}/versions/{version}", response_model=VersionOut, summary="One version")
def get_version(request: Request, name: str, version: int) -> VersionOut:
    return VersionOut.model_validate(_service(request).get_version(name, version))


@router.post("/maps/{name}/versions/{version}/activate", response_model=VersionOut,
             summary="Activate or roll back to a version (hot swap)")  # fmt: skip
def activate(request: Request, name: str, version: int) -> VersionOut:
    return VersionOut.model_validate(_service(request).activate(name, version))


@router.post("/maps/{name}/deactivate", response_model=MapOut,
             summary="Take a map out of service (localize answers 409)")  # fmt: skip
def deactivate(request: Request, name: str) -> MapOut:
    return MapOut.model_validate(_service(request).deactivate(name))


@router.delete("/maps/{name}/versions/{version}", status_code=204,
               summary="Delete an inactive version")  # fmt: skip
def delete_version(request: Request, name: str, version: int) -> Response:
    _service(request).delete_version(name, version)
    return Response(status_code=204)
