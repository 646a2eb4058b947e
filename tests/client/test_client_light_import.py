"""``service.client`` (and the wire models it shares with the server) works in a process where
the server's dependencies cannot be imported at all."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# Every third-party package only the server needs, and every server-side package of ours.
BLOCKED = (
    "fastapi", "starlette", "uvicorn", "multipart", "python_multipart", "sqlalchemy", "sqlite3",
    "sklearn", "scipy", "joblib", "torch", "faiss", "skimage", "PIL", "matplotlib", "safetensors",
    "grpc", "google.protobuf", "redis", "rq", "prometheus_client", "pydantic_settings",
    "threadpoolctl", "typer", "rich",
    "service.api", "service.core", "service.encoding", "service.registry", "service.jobs",
    "service.grpc", "service.imaging", "service.harness", "service.bench", "service.cli",
    "service.settings",
)  # fmt: skip

SCRIPT = textwrap.dedent(
    """
    import sys

    BLOCKED = %r

    class Blocker:
        def find_spec(self, name, path=None, target=None):
            if any(name == b or name.startswith(b + ".") for b in BLOCKED):
                raise ImportError(f"blocked server dependency {name!r} imported by the client")
            return None

    sys.meta_path.insert(0, Blocker())

    import httpx
    import numpy as np

    from service.client import GridplaceClient, TrainingOptions
    from service.errors import DimensionMismatchError, InvalidParameterError

    def handler(request):
        if request.url.path == "/healthz":
            return httpx.Response(200, json={"status": "ok"})
        if request.url.path == "/v1/localize/batch":
            n = len(request.content) // 4 // int(request.url.params["d"])
            return httpx.Response(200, json={"map": "m", "version": 1, "n": n, "index": [3] * n,
                                             "chunk": [0] * n, "confidence": [0.5] * n,
                                             "latency_ms": 1.0})
        return httpx.Response(400, json={"error": "dimension_mismatch", "message": "d=3 not 4"})

    with GridplaceClient("http://server", transport=httpx.MockTransport(handler)) as gp:
        assert gp.health().status == "ok"
        assert gp.localize_batch("m", np.zeros((2, 4))).index == [3, 3]
        try:
            gp.localize("m", [1.0, 2.0, 3.0])
        except DimensionMismatchError as exc:
            assert "d=3" in exc.message
        else:
            raise AssertionError("the error answer was not raised")
        try:
            gp.upload_route("m", b"x", rho=7.0)
        except InvalidParameterError as exc:
            assert "rho" in exc.message
        else:
            raise AssertionError("rho=7 was not refused before the upload")
    assert TrainingOptions(periods="60x60").form() == {"periods": "60,60"}
    leaked = sorted(m for m in sys.modules if any(m == b or m.startswith(b + ".") for b in BLOCKED))
    assert not leaked, leaked
    print("client ok")
    """
)


def test_the_client_imports_and_works_without_server_dependencies() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", SCRIPT % (BLOCKED,)], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip() == "client ok"
