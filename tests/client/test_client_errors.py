"""Error mapping and waiting, with hand-written answers (httpx.MockTransport, no server)."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from service.client import (
    GridplaceClient,
    JobTimeoutError,
    RequestValidationError,
    UnexpectedResponseError,
    error_from_response,
)
from service.errors import (
    ConflictError,
    DimensionMismatchError,
    ForbiddenError,
    GridplaceError,
    InvalidInputError,
    NotFittedError,
    NotFoundError,
    PayloadTooLargeError,
    UnauthorizedError,
    UnavailableError,
)


def _answer(status: int, body: Any = None, text: str | None = None) -> httpx.Response:
    request = httpx.Request("GET", "http://server/v1/x")
    if text is not None:
        return httpx.Response(status, text=text, request=request)
    return httpx.Response(status, json=body, request=request)


@pytest.mark.parametrize(
    ("status", "code", "cls"),
    [
        (404, "not_found", NotFoundError),
        (400, "dimension_mismatch", DimensionMismatchError),
        (400, "invalid_input", InvalidInputError),
        (400, "bad_request", InvalidInputError),  # a code the client does not know: by status
        (401, "unauthorized", UnauthorizedError),
        (403, "forbidden", ForbiddenError),
        (409, "conflict", ConflictError),
        (409, "not_fitted", NotFittedError),
        (413, "payload_too_large", PayloadTooLargeError),
        (422, "validation_error", RequestValidationError),
        (503, "unavailable", UnavailableError),
        (500, "internal_error", GridplaceError),
    ],
)
def test_error_codes_map_to_the_one_hierarchy(
    status: int, code: str, cls: type[GridplaceError]
) -> None:
    err = error_from_response(
        _answer(status, {"error": code, "message": "why", "details": {"k": 1}})
    )
    assert type(err) is cls and err.message == "why" and err.details["k"] == 1
    assert err.details["http_status"] == status
    if err.code != code:
        assert err.details["server_code"] == code


def test_answers_that_are_not_gridplace_errors() -> None:
    proxy = error_from_response(_answer(503, text="<html>upstream down</html>"))
    assert isinstance(proxy, UnavailableError) and "upstream down" in proxy.message
    odd = error_from_response(_answer(418, {"detail": "teapot"}))
    assert isinstance(odd, UnexpectedResponseError) and "418" in odd.message
    crash = error_from_response(_answer(502, text=""))
    assert type(crash) is GridplaceError and "empty body" in crash.message


def _job(state: str) -> dict[str, Any]:
    return {"id": "j1", "map": "m", "state": state, "stage": state, "chunks_done": 0,
            "chunks_total": 0, "created_at": "2026-01-01T00:00:00Z", "started_at": None,
            "finished_at": None, "error": None, "version": None, "idempotency_key": None,
            "timings": {}, "job_id": "j1"}  # fmt: skip


def test_wait_for_job_times_out_and_sends_the_token_only_on_admin_calls() -> None:
    seen: list[httpx.Request] = []

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        if request.url.path == "/healthz":
            return httpx.Response(200, json={"status": "ok"})
        return httpx.Response(200, json=_job("running"))

    with GridplaceClient(
        "http://server", token="s3cret", transport=httpx.MockTransport(handler)
    ) as gp:
        assert gp.health().status == "ok"
        with pytest.raises(JobTimeoutError, match="still running"):
            gp.wait_for_job("j1", timeout=0.05, poll_interval=0.01)
    assert "authorization" not in seen[0].headers
    assert seen[1].headers["authorization"] == "Bearer s3cret"


def test_a_malformed_success_body_is_reported() -> None:
    transport = httpx.MockTransport(lambda r: httpx.Response(200, json=[]))
    gp = GridplaceClient("http://server", transport=transport)
    with gp, pytest.raises(UnexpectedResponseError, match="/healthz"):
        gp.health()


def test_url_and_token_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GRIDPLACE_URL", "gridplace.internal:9000/")
    monkeypatch.setenv("GRIDPLACE_ADMIN_TOKEN", "from-env")
    with GridplaceClient() as gp:
        assert gp.base_url == "http://gridplace.internal:9000" and gp.token == "from-env"
    with GridplaceClient("https://x", token="explicit") as gp:
        assert gp.base_url == "https://x" and gp.token == "explicit"
