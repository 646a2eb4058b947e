"""A bounded schemathesis run against the real server: every public and admin operation of the
OpenAPI schema, positive and negative examples, derandomised (fixed seed). It fails on any 5xx,
any answer outside the documented statuses, content types or response schemas, any
schema-valid request refused as invalid (422), and any schema-invalid request accepted."""

from __future__ import annotations

import os
import time

import pytest
import schemathesis
from contract_helpers import TOKEN
from schemathesis.config import SchemathesisConfig

from service.api.process import ServerProcess

pytestmark = pytest.mark.slow

MAX_EXAMPLES = int(os.environ.get("GRIDPLACE_SCHEMATHESIS_EXAMPLES", "120"))  # per operation and generation mode
SEED = 20260412
# 400/404/409/413: refusals that depend on the data (a descriptor's width against the map, a
# file that is no .npy…), which no schema can state. A 422 means the server's own schema
# validation refused a request its OpenAPI schema accepts: the disagreement this run guards.
POSITIVE_STATUSES = ["2xx", "400", "401", "403", "404", "409", "413"]

# most requests name the served map (random names would all be 404s)
ON_THE_MAP = {"dictionary": "maps", "probability": 0.7}
CONFIG = SchemathesisConfig.from_dict({
    "seed": SEED,
    "dictionaries": {"maps": {"values": ["nordland"]}},
    "parameters": {"path.name": ON_THE_MAP, "query.map": ON_THE_MAP, "body.map": ON_THE_MAP},
    "headers": {"Authorization": f"Bearer {TOKEN}"},
    "generation": {"mode": "all", "max-examples": MAX_EXAMPLES, "deterministic": True,
                   "database": "none"},
    "checks": {"positive_data_acceptance": {"expected-statuses": POSITIVE_STATUSES}},
    "phases": {"stateful": {"enabled": False}},
    "operations": [{  # /readyz answers 503 (documented) while a map is not loaded: map 'broken'
        "include-path": "/readyz",
        "checks": {"not_a_server_error": {"expected-statuses": ["2xx", "3xx", "4xx", "503"]},
                   "positive_data_acceptance": {"expected-statuses": ["2xx", "503"]}},
    }],
    "request-timeout": 30,
})  # fmt: skip

STATS = {"requests": 0, "5xx": 0, "seconds": 0.0}


@pytest.fixture(scope="session")
def api_schema(contract_server: ServerProcess) -> schemathesis.BaseSchema:
    return schemathesis.openapi.from_url(f"{contract_server.url}/openapi.json", config=CONFIG)


schema = schemathesis.pytest.from_fixture("api_schema")


@schema.parametrize()
def test_the_server_keeps_its_schema(case: schemathesis.Case) -> None:
    start = time.perf_counter()
    response = case.call_and_validate(timeout=30)
    STATS["requests"] += 1
    STATS["5xx"] += response.status_code >= 500
    STATS["seconds"] += time.perf_counter() - start
