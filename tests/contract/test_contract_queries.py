"""Localize answers for corrupt maps and extreme values; what the access log keeps (real
server process)."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from contract_helpers import AUTH, TOKEN, D

from service.api.process import ServerProcess

pytestmark = pytest.mark.slow


def test_a_corrupt_artifact_is_reported_as_corrupt_not_as_loading(api: httpx.Client) -> None:
    r = api.post("/v1/localize", json={"map": "broken", "descriptor": [0.0] * D})
    body = r.json()
    assert r.status_code == 500 and body["error"] == "artifact_error", r.text
    assert "corrupt" in body["message"] and "retry" not in body["message"]
    assert "activate" in body["message"]  # what an operator can do about it
    ready = api.get("/readyz")
    assert ready.status_code == 503 and "broken" in ready.json()["errors"]  # unchanged


def test_credentials_in_query_strings_never_reach_the_access_log(
    api: httpx.Client, contract_server: ServerProcess
) -> None:
    secret = "leaked-" + TOKEN
    assert api.get(f"/v1/maps?token={secret}").status_code == 401
    assert api.get(f"/v1/jobs/nope?token={secret}&x=1", headers=AUTH).status_code == 404
    assert api.get(f"/healthz?access_token={secret}&probe=1").status_code == 200
    for name in ("admin_token", "bearer_token", "jwt", "x-token", "gridplace_admin_token",
                 secret):  # any name, or the secret as a name  # fmt: skip
        assert api.get(f"/healthz?{name}={secret}&map=route").status_code == 200
    r = api.post(f"/v1/localize/sequence?map=route&min_speed=0.5&jwt={secret}",
                 content=b"", headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 400  # an unknown query parameter (and no frames)
    assert api.get("/healthz?map=probe2").status_code == 200  # flushes the log before reading
    log = contract_server.log()
    assert '"GET /v1/maps HTTP/1.1" 401' in log and "map=probe2" in log  # the lines are there
    assert '"GET /healthz?***&*** HTTP/1.1" 200' in log
    assert '"GET /healthz?***&map=route HTTP/1.1" 200' in log  # allow-listed values are kept
    assert "/v1/localize/sequence?map=route&min_speed=0.5&*** HTTP" in log
    assert secret not in log and TOKEN not in log


@pytest.mark.parametrize("value", [1e308, -1e308, float(np.finfo(np.float32).max), 1e39])
def test_values_that_overflow_once_normalised_are_refused(api: httpx.Client, value: float) -> None:
    r = api.post("/v1/localize", json={"map": "route", "descriptor": [value] * D})
    assert r.status_code == 400, r.text
    assert r.json()["error"] == "input_overflow" and "normalis" in r.json()["message"]
    one = np.zeros((1, D), np.float32)
    one[0, 5] = np.float32(min(abs(value), float(np.finfo(np.float32).max)))
    r = api.post("/v1/localize/batch", params={"map": "route", "d": D}, content=one.tobytes(),
                 headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 400 and "column 5" in r.json()["message"], r.text


def test_ordinary_values_are_still_answered(api: httpx.Client,
                                            contract_route: tuple[np.ndarray, np.ndarray]) -> None:  # fmt: skip
    r = api.post("/v1/localize/batch", json={"map": "route", "descriptors": contract_route[1][:5].tolist()})
    assert r.status_code == 200 and r.json()["n"] == 5
