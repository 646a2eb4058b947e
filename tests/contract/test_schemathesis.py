"""A bounded schemathesis run against the real server: every public and admin operation of the
OpenAPI schema, positive and negative examples, derandomised (fixed seed). It fails on any 5xx,
any answer outside the documented statuses, content types or response schemas, any
schema-valid request refused as invalid (422), and any schema-invalid request accepted.

The sequence endpoint's JSON body is fuzzed with its ``filter`` options (the run counts the
requests that carry some). The run drives schemathesis through its documented Hypothesis strategies
(``operation.as_strategy``), not its pytest plugin: the plugin's lazy-fixture loader reaches into
pytest's private node attributes and breaks when pytest changes them."""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import hypothesis
import pytest
import schemathesis
from contract_helpers import TOKEN
from schemathesis.config import SchemathesisConfig
from schemathesis.generation import GenerationMode

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


def _runner(operation: schemathesis.APIOperation, mode: GenerationMode,
            stats: dict[str, float]) -> Callable[[], None]:  # fmt: skip
    @hypothesis.settings(max_examples=MAX_EXAMPLES, derandomize=True, database=None,
                         deadline=None, suppress_health_check=list(hypothesis.HealthCheck),
                         phases=[hypothesis.Phase.explicit, hypothesis.Phase.generate])  # fmt: skip
    @hypothesis.given(case=operation.as_strategy(generation_mode=mode))
    def run(case: schemathesis.Case) -> None:
        start = time.perf_counter()
        response = case.call_and_validate(timeout=30)
        stats["requests"] += 1
        stats["5xx"] += response.status_code >= 500
        body = case.body if isinstance(case.body, dict) else {}
        stats["filter_options"] += isinstance(body.get("filter"), dict) and bool(body["filter"])
        stats["seconds"] += time.perf_counter() - start

    return run


def test_the_server_keeps_its_schema(contract_server: ServerProcess) -> None:
    schema = schemathesis.openapi.from_url(f"{contract_server.url}/openapi.json", config=CONFIG)
    stats = {"requests": 0, "5xx": 0, "seconds": 0.0, "filter_options": 0}
    failures: list[str] = []
    operations = 0
    for result in schema.get_all_operations():
        operation = result.ok()  # a schema error raises here: the schema must resolve
        operations += 1
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
            try:
                _runner(operation, mode, stats)()
            except hypothesis.errors.Unsatisfiable:
                if mode is GenerationMode.POSITIVE:  # every operation has valid requests
                    failures.append(f"{operation.label}: no schema-valid request generated")
                # else: the operation takes no input that could be schema-invalid
            except Exception as exc:  # every operation is run; the failures are reported together
                if mode is GenerationMode.NEGATIVE and "Unsupported type" in str(exc):
                    continue  # schemathesis cannot build a schema-invalid multipart binary body
                failures.append(f"{operation.label} ({mode.value}): {exc}")
    assert not failures, "\n\n".join(failures)  # a 5xx fails its check (but /readyz's 503)
    assert operations >= 10, f"only {operations} operations in the schema"
    assert stats["requests"] >= operations, stats
    # the sequence filter's options resolve in the schema, so the fuzzer sends them
    assert stats["filter_options"] >= 5, stats
    print(f"schemathesis: {operations} operations, {stats}")
