"""Hostile job-listing and upload inputs against a real ``gridplace serve`` on each registry
(the SQLite file and a scratch PostgreSQL database): 4xx naming the problem, never a 500."""

from __future__ import annotations

import base64
import io
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from service.api.process import ServerProcess
from service.encoding.synthetic import smooth_route
from test_server import AUTH, TOKEN

pytestmark = pytest.mark.slow


def _npy(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def api(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[httpx.Client]:
    env = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_TRAIN_WORKERS": "1"}
    if request.param == "postgresql":
        env["GRIDPLACE_REGISTRY_URL"] = request.getfixturevalue("pg_registry_url")
    data: Path = tmp_path_factory.mktemp(f"jobs-{request.param}")
    with ServerProcess(data, env=env) as srv, httpx.Client(base_url=srv.url, timeout=30) as c:
        yield c


def _cursor(raw: bytes) -> str:
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


@pytest.mark.parametrize("cursor", [
    _cursor(b"[" * 20_000 + b"]" * 20_000),  # nested beyond the JSON parser's recursion
    "[" * 5_000,  # not even base64
    _cursor(b'[["2026-01-01T00:00:00+00:00"], "x"]'),
    _cursor(b'["2026-01-01T00:00:00+00:00", "a\\u0000b"]'),  # a NUL in the job id
    _cursor(b'["2026-01-01T00:00:00\\u0000", "x"]'),
])  # fmt: skip
def test_a_malformed_cursor_is_400(api: httpx.Client, cursor: str) -> None:
    r = api.get("/v1/jobs", params={"cursor": cursor}, headers=AUTH)
    assert r.status_code == 400, r.text
    assert "invalid job list cursor" in r.json()["message"]


def test_a_nul_in_a_job_id_is_404(api: httpx.Client) -> None:
    for path in ("/v1/jobs/%00", "/v1/jobs/a%00b"):
        r = api.get(path, headers=AUTH)
        assert r.status_code == 404, r.text
        assert "no training job" in r.json()["message"]


def test_the_cursor_pages_through_jobs(api: httpx.Client) -> None:
    """The listing's own cursors still work after the checks above."""
    ref = smooth_route(40, 8, seed=3).reference  # SYNTHETIC
    for k in range(3):
        r = api.post("/v1/maps/pages/routes", headers={**AUTH, "Idempotency-Key": f"p{k}"},
                     files={"file": ("r.npy", _npy(ref + k))}, data={"trainer": "ridge"})  # fmt: skip
        assert r.status_code == 202, r.text
    seen: list[str] = []
    cursor = None
    while True:
        params = {"map": "pages", "limit": 1, **({"cursor": cursor} if cursor else {})}
        page = api.get("/v1/jobs", params=params, headers=AUTH).json()
        seen += [j["id"] for j in page["jobs"]]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert len(seen) == len(set(seen)) == 3


@pytest.mark.parametrize("place", [2**63, 2**64 - 1])
def test_uint64_places_beyond_int64_are_400(api: httpx.Client, place: int) -> None:
    r = smooth_route(20, 8, seed=4)  # SYNTHETIC
    places = np.arange(20, dtype=np.uint64)
    places[7] = place
    files = [("file", ("a.npy", _npy(r.reference))), ("file", ("b.npy", _npy(r.query))),
             ("places", ("pa.npy", _npy(np.arange(20, dtype=np.uint64)))),
             ("places", ("pb.npy", _npy(places)))]  # fmt: skip
    resp = api.post("/v1/maps/wild/routes", headers=AUTH, files=files, data={"trainer": "ridge"})
    assert resp.status_code == 400, resp.text
    assert f"place {place} at row 7" in resp.json()["message"]
