"""Deployment files, validated without a Docker engine or a cluster."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
SETTINGS_ENV = {f"GRIDPLACE_{name.upper()}" for name in Settings.model_fields}
DEFAULTS = Settings()


def load_all(path: Path) -> list[dict]:
    return [doc for doc in yaml.safe_load_all(path.read_text()) if doc]


def test_compose_services_ports_env_and_volumes() -> None:
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = compose["services"]
    assert {"api", "worker", "redis"} <= set(services)
    assert services["api"]["command"] == ["serve"]
    assert services["worker"]["command"] == ["worker"]
    ports = {p.split(":")[1] for p in services["api"]["ports"]}
    assert ports == {str(DEFAULTS.port), str(DEFAULTS.grpc_port)}
    for name in ("api", "worker"):
        env = services[name]["environment"]
        unknown = {k for k in env if k.startswith("GRIDPLACE_")} - SETTINGS_ENV
        assert not unknown, f"{name} sets unknown settings {unknown}"
        assert env["GRIDPLACE_REDIS_URL"].startswith("redis://redis:")
        for vol in services[name]["volumes"]:
            assert vol.split(":")[0] in compose["volumes"]
            assert vol.split(":")[1] == env["GRIDPLACE_DATA_DIR"]
    for svc in services.values():
        for dep in svc.get("depends_on", {}):
            assert dep in services
    # workers scale: no fixed container name or host port
    assert "container_name" not in services["worker"] and "ports" not in services["worker"]


def test_kubernetes_manifests() -> None:
    k8s = ROOT / "deploy" / "k8s"
    kustom = yaml.safe_load((k8s / "kustomization.yaml").read_text())
    docs = [d for f in kustom["resources"] for d in load_all(k8s / f)]
    kinds = {(d["kind"], d["metadata"]["name"]) for d in docs}
    assert ("Deployment", "gridplace-api") in kinds
    assert ("Deployment", "gridplace-worker") in kinds
    assert ("PersistentVolumeClaim", "gridplace-data") in kinds
    assert ("Service", "gridplace-api") in kinds and ("Service", "gridplace-redis") in kinds
    pvc = next(d for d in docs if d["kind"] == "PersistentVolumeClaim")
    assert pvc["spec"]["accessModes"] == ["ReadWriteMany"]
    config = next(d for d in docs if d["kind"] == "ConfigMap")
    assert set(config["data"]) <= SETTINGS_ENV
    api = next(d for d in docs if d["metadata"]["name"] == "gridplace-api" and d["kind"] == "Deployment")
    container = api["spec"]["template"]["spec"]["containers"][0]
    assert container["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert container["livenessProbe"]["httpGet"]["path"] == "/healthz"
    ports = {p["containerPort"] for p in container["ports"]}
    assert ports == {DEFAULTS.port, DEFAULTS.grpc_port}
    token = next(e for e in container["env"] if e["name"] == "GRIDPLACE_ADMIN_TOKEN")
    assert token["valueFrom"]["secretKeyRef"]["name"] == "gridplace-admin"
    for doc in docs:
        if doc["kind"] == "Deployment":
            for c in doc["spec"]["template"]["spec"]["containers"]:
                assert c["resources"]["requests"] and c["resources"]["limits"]
                for e in c.get("env", []):
                    if e["name"].startswith("GRIDPLACE_"):
                        assert e["name"] in SETTINGS_ENV


def test_dockerfile_matches_the_settings() -> None:
    text = (ROOT / "Dockerfile").read_text()
    assert re.search(r"^EXPOSE\s+(\d+)\s+(\d+)\s*$", text, re.M).groups() == (
        str(DEFAULTS.port), str(DEFAULTS.grpc_port),
    )
    assert 'ENTRYPOINT ["gridplace"]' in text and 'CMD ["serve"]' in text
    assert re.search(r"^USER\s+gridplace", text, re.M), "runs as a non-root user"
    assert "HEALTHCHECK" in text and "/healthz" in text
    assert 'VOLUME ["/data"]' in text
    assert text.count("FROM ") >= 2, "multi-stage build"
    assert "torch==2.13.0" in text
    for env in re.findall(r"(GRIDPLACE_[A-Z_]+)=", text):
        assert env in SETTINGS_ENV
    for src in re.findall(r"^COPY (?!--from)(.+?) \S+$", text, re.M):
        for part in src.split():
            assert (ROOT / part).exists(), f"Dockerfile copies missing {part}"


@pytest.mark.parametrize("command", ["serve", "worker"])
def test_commands_used_by_the_deployment_exist(command: str) -> None:
    from typer.main import get_command

    from service.cli import app

    assert command in get_command(app).commands  # type: ignore[attr-defined]
