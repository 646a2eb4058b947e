"""Every REST call as data (method, path, body, how to read the answer).

The sync and async clients only differ in how they send a :class:`Call`; what goes over the
wire and how the answer is read is written once, here.
"""

from __future__ import annotations

import base64
import io
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Generic, TypeVar
from urllib.parse import quote

import httpx
import numpy as np
from numpy.typing import ArrayLike
from pydantic import TypeAdapter, ValidationError

from service.client.errors import UnexpectedResponseError
from service.errors import EmptyInputError, InvalidInputError, InvalidParameterError
from service.wire import (
    AppendOptions,
    BatchLocalization,
    Health,
    Job,
    JobPage,
    Localization,
    MapDetail,
    MapSummary,
    Readiness,
    SequenceFilterOptions,
    SequenceLocalization,
    TrainingOptions,
    Version,
    parse_tags,
)

T = TypeVar("T")
DEFAULT_URL = "http://127.0.0.1:8080"
RouteSource = str | os.PathLike[str] | np.ndarray | bytes
ImageSource = str | os.PathLike[str] | bytes


@dataclass
class Call(Generic[T]):
    """One HTTP request and the reader of its successful answer."""

    method: str
    path: str
    read: Callable[[httpx.Response], T]
    admin: bool = False
    kwargs: dict[str, Any] = field(default_factory=dict)
    also_ok: frozenset[int] = frozenset()  # non-2xx statuses that still carry an answer
    files: list[IO[bytes]] = field(default_factory=list)  # closed once sent

    def close(self) -> None:
        for fh in self.files:
            fh.close()


def _reader(kind: Any) -> Callable[[httpx.Response], Any]:
    adapter: TypeAdapter[Any] = TypeAdapter(kind)

    def read(response: httpx.Response) -> Any:
        try:
            return adapter.validate_json(response.content)
        except ValidationError as exc:
            raise UnexpectedResponseError(
                f"{response.request.method} {response.request.url.path} answered "
                f"{response.status_code} with a body that is not a {kind}: {exc.errors()[:2]}"
            ) from exc

    return read


def _nothing(_: httpx.Response) -> None:
    return None


def _seg(text: str) -> str:
    return quote(str(text), safe="")


def as_float32_rows(X: ArrayLike, what: str) -> np.ndarray:
    """``X`` as a C-contiguous little-endian float32 matrix (one row per descriptor)."""
    try:
        arr = np.asarray(X, dtype="<f4")
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{what} is not numeric: {exc}") from exc
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise InvalidInputError(f"{what} must be one descriptor or a 2-D matrix, got {arr.ndim}-D")
    if arr.size == 0:
        raise EmptyInputError(f"{what} is empty")
    return np.ascontiguousarray(arr)


def _read_image(image: ImageSource) -> tuple[str, bytes]:
    if isinstance(image, bytes):
        return "image", image
    path = Path(image)
    return path.name, path.read_bytes()


def _npy_bytes(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


def read_route_file(route: str | os.PathLike[str], filename: str | None) -> tuple[bytes, str]:
    """A route file's bytes and upload name (clear error when it is missing)."""
    path = Path(route)
    if not path.is_file():
        raise InvalidInputError(f"route file not found: {path}", path=str(path))
    return path.read_bytes(), filename or path.name


def options_of(options: TrainingOptions | None, params: dict[str, Any]) -> TrainingOptions:
    """Merge keyword parameters into the options, refusing unknown names and bad values."""
    merged = {**(options.model_dump(exclude_none=True) if options else {}), **params}
    try:
        return TrainingOptions(**merged)
    except ValidationError as exc:
        raise InvalidParameterError(f"invalid training parameters: {_messages(exc)}") from exc


def _messages(exc: ValidationError) -> str:
    return "; ".join(f"{'.'.join(map(str, e['loc'])) or 'options'}: {e['msg']}" for e in exc.errors())


# -- the calls ------------------------------------------------------------------------------
def health() -> Call[Health]:
    return Call("GET", "/healthz", _reader(Health))


def ready() -> Call[Readiness]:
    return Call("GET", "/readyz", _reader(Readiness), also_ok=frozenset({503}))


def localize(
    map_name: str, descriptor: ArrayLike | None, image: ImageSource | None,
    vehicle_id: str | None = None, adaptation: bool | None = None,
    vehicle_key: str | None = None, reset: bool | None = None, condition: str | None = None,
) -> Call[Localization]:  # fmt: skip
    if (descriptor is None) == (image is None):
        raise InvalidInputError("localize needs exactly one of descriptor or image")
    read = _reader(Localization)
    fields = (("vehicle_id", vehicle_id), ("adaptation", adaptation),
              ("vehicle_key", vehicle_key), ("reset", reset), ("condition", condition))  # fmt: skip
    who: dict[str, Any] = {k: v for k, v in fields if v is not None}
    if image is not None:
        name, data = _read_image(image)
        form = {k: (str(v).lower() if isinstance(v, bool) else v) for k, v in who.items()}
        return Call("POST", "/v1/localize", read, kwargs={
            "data": {"map": map_name, **form}, "files": {"image": (name, data)}})  # fmt: skip
    assert descriptor is not None
    row = as_float32_rows(descriptor, "descriptor")
    if row.shape[0] != 1:
        raise InvalidInputError(f"localize takes one descriptor ({row.shape[0]} rows given); "
                                "use localize_batch")  # fmt: skip
    b64 = base64.b64encode(row.tobytes()).decode("ascii")
    return Call(
        "POST", "/v1/localize", read,
        kwargs={"json": {"map": map_name, "descriptor_b64": b64, **who}},
    )  # fmt: skip


def _condition(condition: str | None) -> dict[str, str]:
    return {} if condition is None else {"condition": condition}


def localize_batch(map_name: str, descriptors: ArrayLike,
                   condition: str | None = None) -> Call[BatchLocalization]:  # fmt: skip
    X = as_float32_rows(descriptors, "descriptors")
    return Call("POST", "/v1/localize/batch", _reader(BatchLocalization), kwargs={
        "params": {"map": map_name, "d": X.shape[1], **_condition(condition)}, "content": X.tobytes(),
        "headers": {"Content-Type": "application/octet-stream"}})  # fmt: skip


def localize_sequence(
    map_name: str, descriptors: ArrayLike, filter_params: dict[str, Any],
    adaptation: bool | None = None, odometry: Sequence[float | None] | None = None,
    condition: str | None = None,
) -> Call[SequenceLocalization]:  # fmt: skip
    """Rows in driving order, one binary float32 request (JSON with base64 rows when
    ``odometry`` is given: one displacement per row, reference frames, ``None`` for a row
    without); filter options are checked against their static bounds before anything is sent
    (the server checks the rest). ``adaptation`` unset: the server's default."""
    X = as_float32_rows(descriptors, "descriptors")
    try:
        options = SequenceFilterOptions(**filter_params).given()
    except ValidationError as exc:
        raise InvalidParameterError(f"invalid sequence filter options: {_messages(exc)}") from exc
    if odometry is not None:
        body: dict[str, Any] = {
            "map": map_name, "descriptors_b64": base64.b64encode(X.tobytes()).decode(),
            "odometry": [None if u is None else float(u) for u in odometry],
        }  # fmt: skip
        if options:
            body["filter"] = options
        if adaptation is not None:
            body["adaptation"] = adaptation
        body.update(_condition(condition))
        return Call("POST", "/v1/localize/sequence", _reader(SequenceLocalization),
                    kwargs={"json": body})  # fmt: skip
    if adaptation is not None:
        options["adaptation"] = adaptation
    params = {k: (str(v).lower() if isinstance(v, bool) else v) for k, v in options.items()}
    return Call("POST", "/v1/localize/sequence", _reader(SequenceLocalization), kwargs={
        "params": {**params, "map": map_name, "d": X.shape[1], **_condition(condition)},
        "content": X.tobytes(),
        "headers": {"Content-Type": "application/octet-stream"}})  # fmt: skip


def localize_images(map_name: str, images: Sequence[ImageSource],
                    condition: str | None = None) -> Call[BatchLocalization]:  # fmt: skip
    if not images:
        raise EmptyInputError("localize_images needs at least one image")
    files = [("images", _read_image(img)) for img in images]
    return Call("POST", "/v1/localize/batch", _reader(BatchLocalization), kwargs={
        "data": {"map": map_name, **_condition(condition)}, "files": files})  # fmt: skip


def upload_route(
    map_name: str,
    route: RouteSource | Sequence[RouteSource],
    options: TrainingOptions,
    idempotency_key: str | None,
    filename: str | None,
    places: Sequence[RouteSource] | None = None,
    names: Sequence[str | None] | None = None,
) -> Call[Job]:
    """One route file, or several (traversals of the same places: one ``file`` field each,
    ``names`` their upload names), and optionally one place-index file (or int array) per
    traversal as ``places`` fields."""
    routes = _as_list(route)
    if not routes:
        raise EmptyInputError("upload_route needs at least one route file")
    given = list(names) if names else ([filename] if len(routes) == 1 else [])
    files, opened = _upload_parts(
        routes, places, given, lambda i: f"route-{i + 1}.npy" if len(routes) > 1 else "route.npy",
        "route file(s)", "file",
    )  # fmt: skip
    headers = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
    return Call("POST", f"/v1/maps/{_seg(map_name)}/routes", _reader(Job), admin=True, kwargs={
        "files": files, "data": options.form(), "headers": headers}, files=opened)  # fmt: skip


def append_traversals(
    map_name: str, version: int, traversals: RouteSource | Sequence[RouteSource],
    options: AppendOptions, places: Sequence[RouteSource] | None = None,
) -> Call[Any]:  # fmt: skip
    """One traversal file (or array), or several, each optionally with its place index, and
    the append options as form fields; answered by the new version, or with ``retrain`` by
    the training job."""
    routes = _as_list(traversals)
    if not routes:
        raise EmptyInputError("append_traversals needs at least one traversal")
    files, opened = _upload_parts(routes, places, [], lambda i: f"traversal-{i + 1}.npy",
                                  "traversal(s)", "traversal")  # fmt: skip
    path = f"/v1/maps/{_seg(map_name)}/versions/{int(version)}/traversals"
    return Call("POST", path, _reader(Job if options.retrain else Version), admin=True,
                kwargs={"files": files, "data": options.form()}, files=opened)  # fmt: skip


def append_options(tags: Sequence[str], extend: bool, whiten: bool | None,
                   activate: bool, retrain: bool = False) -> AppendOptions:  # fmt: skip
    """Validated append options (a bad tag is an error naming it before anything is sent)."""
    parse_tags(list(tags))
    fields: dict[str, Any] = {"tag": list(tags), "extend": extend}
    if activate:
        fields["activate"] = activate
    if whiten is not None:
        fields["whiten"] = whiten
    if retrain:
        fields["retrain"] = True
    try:
        options = AppendOptions(**fields)
    except ValidationError as exc:
        raise InvalidParameterError(f"invalid append options: {_messages(exc)}") from exc
    options.check_retrain()
    return options


def _as_list(source: RouteSource | Sequence[RouteSource]) -> list[RouteSource]:
    return list(source) if isinstance(source, list | tuple) else [source]


def _upload_parts(
    routes: list[RouteSource], places: Sequence[RouteSource] | None, names: list[str | None],
    default: Callable[[int], str], counted: str, per: str,
) -> tuple[list[tuple[str, tuple[str, bytes | IO[bytes]]]], list[IO[bytes]]]:
    """The ``file`` part of every route (named ``names[i]``, else by its file, else
    ``default(i)``) and the ``places`` part of each, and the files opened for streaming (all
    closed again if a part fails); ``counted`` and ``per`` word a count mismatch."""
    if places is not None and len(places) != len(routes):
        raise InvalidInputError(
            f"{len(routes)} {counted} need {len(routes)} place-index file(s) (one per "
            f"{per}, in the same order), got {len(places)}", files=len(routes),
            places=len(places),
        )  # fmt: skip
    opened: list[IO[bytes]] = []
    try:
        files = [("file", _upload_part(r, names[i] if i < len(names) else None, default(i),
                                       opened)) for i, r in enumerate(routes)]  # fmt: skip
        files += [("places", _upload_part(p, None, f"places-{i + 1}.npy", opened))
                  for i, p in enumerate(places or [])]  # fmt: skip
    except BaseException:
        for fh in opened:
            fh.close()
        raise
    return files, opened


def _upload_part(source: RouteSource, filename: str | None, default: str,
                 opened: list[IO[bytes]]) -> tuple[str, bytes | IO[bytes]]:  # fmt: skip
    """A multipart file part: an array (as ``.npy``), bytes, or a file opened for streaming."""
    if isinstance(source, np.ndarray):
        return filename or default, _npy_bytes(source)
    if isinstance(source, bytes):
        return filename or default, source
    path = Path(source)
    if not path.is_file():
        raise InvalidInputError(f"route file not found: {path}", path=str(path))
    fh = path.open("rb")
    opened.append(fh)
    return filename or path.name, fh


def get_job(job_id: str) -> Call[Job]:
    return Call("GET", f"/v1/jobs/{_seg(job_id)}", _reader(Job), admin=True)


def list_jobs(map_name: str | None = None, states: Sequence[str] | None = None,
              limit: int = 50, cursor: str | None = None) -> Call[JobPage]:  # fmt: skip
    params: dict[str, Any] = {"limit": limit}
    if map_name is not None:
        params["map"] = map_name
    if states:
        params["state"] = list(states)
    if cursor is not None:
        params["cursor"] = cursor
    return Call("GET", "/v1/jobs", _reader(JobPage), admin=True, kwargs={"params": params})


def list_maps() -> Call[list[MapSummary]]:
    return Call("GET", "/v1/maps", _reader(list[MapSummary]), admin=True)


def get_map(name: str) -> Call[MapDetail]:
    return Call("GET", f"/v1/maps/{_seg(name)}", _reader(MapDetail), admin=True)


def list_versions(name: str) -> Call[list[Version]]:
    return Call("GET", f"/v1/maps/{_seg(name)}/versions", _reader(list[Version]), admin=True)


def get_version(name: str, version: int) -> Call[Version]:
    return Call(
        "GET", f"/v1/maps/{_seg(name)}/versions/{int(version)}", _reader(Version), admin=True
    )


def activate(name: str, version: int) -> Call[Version]:
    path = f"/v1/maps/{_seg(name)}/versions/{int(version)}/activate"
    return Call("POST", path, _reader(Version), admin=True)


def deactivate(name: str) -> Call[MapSummary]:
    return Call("POST", f"/v1/maps/{_seg(name)}/deactivate", _reader(MapSummary), admin=True)


def delete_version(name: str, version: int) -> Call[None]:
    return Call("DELETE", f"/v1/maps/{_seg(name)}/versions/{int(version)}", _nothing, admin=True)
