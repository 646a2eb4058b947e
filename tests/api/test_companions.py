"""The companion hook through which gRPC runs beside REST over the same service layer."""

from __future__ import annotations

from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.companions import discover_companions
from service.core.context import ServiceContext, build_context


class Recorder:
    name = "recorder"

    def __init__(self) -> None:
        self.events: list[str] = []
        self.context: ServiceContext | None = None

    def start(self, context: ServiceContext) -> None:
        self.context = context
        self.events.append("start")

    def stop(self) -> None:
        self.events.append("stop")


def test_companions_share_the_context_and_stop_first(settings, registry, backend) -> None:
    ctx = build_context(settings, registry=registry, backend=backend)
    rec = Recorder()
    app = create_app(settings, context=ctx, companions=[rec])
    with TestClient(app):
        assert rec.events == ["start"] and rec.context is ctx
        assert rec.context.service.store is ctx.store
    assert rec.events == ["start", "stop"]


def test_a_missing_transport_module_means_no_companion(settings, monkeypatch) -> None:
    import service.api.companions as companions

    monkeypatch.setattr(companions, "COMPANION_MODULES", ("service.grpc_not_in_this_build.server",))
    assert discover_companions(settings) == []


def test_the_grpc_companion_is_discovered(settings) -> None:
    found = discover_companions(settings.model_copy(update={"grpc_port": 0}))
    # grpc_port 0 turns gRPC off; any other port yields the gRPC companion
    assert found == []
    names = [c.name for c in discover_companions(settings.model_copy(update={"grpc_port": 50999}))]
    assert names and all("grpc" in n for n in names)


def test_openapi_documents_bearer_auth(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    assert "HTTPBearer" in spec["components"]["securitySchemes"]
    assert spec["paths"]["/v1/maps"]["get"]["security"] == [{"HTTPBearer": []}]
    assert "security" not in spec["paths"]["/v1/localize"]["post"]
