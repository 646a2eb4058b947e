"""Version numbers and methods of the admin paths, against a real server process."""

from __future__ import annotations

import httpx
import pytest
from contract_helpers import AUTH

pytestmark = pytest.mark.slow
HUGE = 2**63  # one above SQLite's largest INTEGER


@pytest.mark.parametrize(("method", "path"), [
    ("GET", "/v1/maps/route/versions/{v}"),
    ("POST", "/v1/maps/route/versions/{v}/activate"),
    ("DELETE", "/v1/maps/route/versions/{v}"),
])  # fmt: skip
def test_version_numbers_beyond_sqlite_integers_are_4xx(api: httpx.Client, method: str,
                                                        path: str) -> None:  # fmt: skip
    for version, status in ((HUGE, 422), (10**30, 422), (0, 422), (HUGE - 1, 404)):
        r = api.request(method, path.format(v=version), headers=AUTH)
        assert r.status_code == status, (version, r.text)
        assert r.json()["error"] in ("validation_error", "not_found")
        if status == 422:
            assert "version" in r.json()["message"]


def test_options_names_every_method_of_the_path(api: httpx.Client) -> None:
    r = api.options("/v1/maps/route/versions/1", headers=AUTH)
    assert r.status_code == 405
    assert {m.strip() for m in r.headers["allow"].split(",")} >= {"GET", "DELETE"}
    r = api.request("PUT", "/v1/maps/route/versions/1", headers=AUTH)
    assert r.status_code == 405 and r.json()["error"] == "method_not_allowed"
    assert {m.strip() for m in r.headers["allow"].split(",")} >= {"GET", "DELETE"}
