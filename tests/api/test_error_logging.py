"""How refusals are logged: a capacity refusal is expected under load (a warning the operator
can rate), a server fault is an error."""

from __future__ import annotations

import logging

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from service.api.errors import install_error_handlers
from service.errors import CapacityError, UnavailableError


def _app() -> FastAPI:
    app = FastAPI()
    install_error_handlers(app)

    @app.get("/full")
    def full() -> None:
        raise CapacityError("the server holds GRIDPLACE_MAX_PUBLIC_REQUESTS requests")

    @app.get("/down")
    def down() -> None:
        raise UnavailableError("the registry is unreachable")

    return app


@pytest.mark.parametrize(("path", "status", "level"), [
    ("/full", 503, logging.WARNING), ("/down", 503, logging.ERROR)])  # fmt: skip
def test_capacity_refusals_are_warnings_and_faults_errors(
        caplog: pytest.LogCaptureFixture, path: str, status: int, level: int) -> None:  # fmt: skip
    with TestClient(_app()) as client, caplog.at_level(logging.WARNING, "gridplace.api"):
        r = client.get(path)
    assert r.status_code == status
    records = [rec for rec in caplog.records if rec.name == "gridplace.api"]
    assert [rec.levelno for rec in records] == [level]
    assert (r.headers.get("Retry-After") is not None) == (path == "/full")
