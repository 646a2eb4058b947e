"""/healthz, /readyz, /metrics and the OpenAPI document."""

from __future__ import annotations

from fastapi.testclient import TestClient


def test_health_and_readiness(client: TestClient, trained: str) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    r = client.get("/readyz")
    assert r.status_code == 200 and r.json()["loaded"] == {trained: 1}


def test_metrics_expose_requests_latency_models_and_queue(client: TestClient, trained: str, auth) -> None:
    client.post("/v1/localize", json={"map": trained, "descriptor": [0.1] * 32})
    client.post("/v1/localize", json={"map": trained, "descriptor": [0.1] * 3})
    client.get("/v1/jobs/job-1", headers=auth)
    text = client.get("/metrics").text
    for needle in (
        'gridplace_http_requests_total{method="POST",route="/v1/localize",status="200"} 1.0',
        'gridplace_http_requests_total{method="POST",route="/v1/localize",status="400"} 1.0',
        'gridplace_http_request_seconds_bucket{le="0.005",method="POST",route="/v1/localize"',
        'gridplace_localize_seconds_count{input="descriptor",map="synthetic"} 1.0',
        'gridplace_localize_queries_total{input="descriptor",map="synthetic"} 1.0',
        "gridplace_loaded_versions 1.0",
        'gridplace_active_version{map="synthetic"} 1.0',
        'gridplace_model_footprint_bytes{kind="actual",map="synthetic"}',
        "gridplace_queue_depth 0.0",
        'gridplace_training_job_seconds_count{state="succeeded"} 1.0',
        "gridplace_training_jobs_submitted_total 1.0",
    ):
        assert needle in text, needle
    assert 'route="/v1/jobs/{job_id}"' in text  # templates, not raw paths


def test_unknown_routes_and_methods_are_json(client: TestClient) -> None:
    r = client.get("/v1/nope")
    assert r.status_code == 404 and r.json()["error"] == "not_found"
    r = client.get("/v1/localize")
    assert r.status_code == 405 and r.json()["error"] == "method_not_allowed"


def test_openapi_documents_every_endpoint(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    paths = set(spec["paths"])
    assert {"/v1/localize", "/v1/localize/batch", "/v1/maps/{name}/routes", "/v1/jobs/{job_id}",
            "/v1/maps", "/v1/maps/{name}", "/v1/maps/{name}/versions",
            "/v1/maps/{name}/versions/{version}/activate", "/healthz", "/readyz",
            "/metrics"} <= paths  # fmt: skip
    body = spec["paths"]["/v1/localize/batch"]["post"]["requestBody"]["content"]
    assert {"application/json", "multipart/form-data", "application/octet-stream"} <= set(body)
    assert client.get("/docs").status_code == 200
