"""A long schemathesis run against a real ``gridplace serve`` (not part of the suite: the suite
runs ``test_schemathesis.py`` with 120 examples). The server and its data are the contract
tests' (maps ``route``, ``broken``, ``nordland``); the checks are the suite's.

    python tests/contract/fuzz_run.py --examples 400 --no-token   # public callers
    python tests/contract/fuzz_run.py --examples 150              # with the admin token

Prints one JSON line: requests, 5xx answers (other than /readyz's documented 503), requests
that carried sequence filter options, failures by operation.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import hypothesis
import schemathesis
from schemathesis.config import SchemathesisConfig
from schemathesis.generation import GenerationMode

sys.path.insert(0, str(Path(__file__).parent))
from contract_helpers import ENV, TOKEN, D, N  # noqa: E402
from test_schemathesis import ON_THE_MAP, POSITIVE_STATUSES, SEED  # noqa: E402

from service.api.process import ServerProcess  # noqa: E402
from service.encoding import ModelParams, build_model  # noqa: E402
from service.encoding.artifacts import TENSORS  # noqa: E402
from service.encoding.synthetic import smooth_route  # noqa: E402
from service.registry import Registry  # noqa: E402


def _data() -> Path:
    data = Path(tempfile.mkdtemp(prefix="gridplace-fuzz-"))
    registry = Registry(data)
    params = ModelParams.parse(trainer="ridge", n_patterns=2)
    model = build_model(params).fit(smooth_route(N, D, seed=21).reference)  # SYNTHETIC
    for name in ("route", "broken", "nordland"):
        registry.publish(name, model, params=params.model_dump(mode="json"), extractor=None,
                         metrics={}, job_id=None)  # fmt: skip
    tensors = registry.artifact_dir("broken", 1) / TENSORS  # corrupt: its sha256 no longer matches
    tensors.chmod(0o644)
    blob = bytearray(tensors.read_bytes())
    blob[-16:] = bytes(16)
    tensors.write_bytes(bytes(blob))
    return data


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--examples", type=int, default=400)
    ap.add_argument("--no-token", action="store_true")
    args = ap.parse_args()
    config = {
        "seed": SEED, "dictionaries": {"maps": {"values": ["nordland"]}},
        "parameters": {"path.name": ON_THE_MAP, "query.map": ON_THE_MAP, "body.map": ON_THE_MAP},
        "generation": {"mode": "all", "max-examples": args.examples, "deterministic": True,
                       "database": "none"},
        "checks": {"positive_data_acceptance": {"expected-statuses": POSITIVE_STATUSES}},
        "phases": {"stateful": {"enabled": False}},
        "operations": [{"include-path": "/readyz", "checks": {
            "not_a_server_error": {"expected-statuses": ["2xx", "3xx", "4xx", "503"]},
            "positive_data_acceptance": {"expected-statuses": ["2xx", "503"]}}}],
        "request-timeout": 60,
    }  # fmt: skip
    if not args.no_token:
        config["headers"] = {"Authorization": f"Bearer {TOKEN}"}
    stats = {"requests": 0, "5xx": 0, "filter_options": 0, "seconds": 0.0}
    failures: dict[str, str] = {}
    srv = ServerProcess(_data(), env=ENV).start(timeout_s=300)
    try:
        schema = schemathesis.openapi.from_url(f"{srv.url}/openapi.json",
                                               config=SchemathesisConfig.from_dict(config))  # fmt: skip
        for result in schema.get_all_operations():
            operation = result.ok()
            for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):

                @hypothesis.settings(max_examples=args.examples, derandomize=True, database=None,
                                     deadline=None, suppress_health_check=list(hypothesis.HealthCheck),
                                     phases=[hypothesis.Phase.explicit, hypothesis.Phase.generate])  # fmt: skip
                @hypothesis.given(case=operation.as_strategy(generation_mode=mode))
                def run(case: schemathesis.Case) -> None:
                    start = time.perf_counter()
                    response = case.call_and_validate(timeout=60)
                    stats["requests"] += 1
                    stats["5xx"] += response.status_code >= 500 and case.path != "/readyz"
                    body = case.body if isinstance(case.body, dict) else {}
                    stats["filter_options"] += isinstance(body.get("filter"), dict) and bool(body["filter"])
                    stats["seconds"] += time.perf_counter() - start

                try:
                    run()
                except hypothesis.errors.Unsatisfiable:
                    pass
                except Exception as exc:  # noqa: BLE001 - reported
                    failures[f"{operation.label} ({mode.value})"] = str(exc)[:2000]
    finally:
        srv.stop()
    print(json.dumps({"token": not args.no_token, "examples": args.examples, **stats,
                      "failures": failures}))  # fmt: skip


if __name__ == "__main__":
    main()
