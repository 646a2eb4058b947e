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


def test_compose_keeps_the_registry_in_postgres_and_only_artifacts_on_the_volume() -> None:
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = compose["services"]
    pg = services["postgres"]
    assert pg["image"].startswith("postgres:") and "pg_isready" in pg["healthcheck"]["test"]
    db = pg["environment"]["POSTGRES_DB"]
    for name in ("api", "worker"):
        env = services[name]["environment"]
        url = env["GRIDPLACE_REGISTRY_URL"]
        assert url.startswith("postgresql://") and url.endswith(f"@postgres:5432/{db}")
        assert "GRIDPLACE_REGISTRY_JOURNAL_MODE" not in env  # SQLite only
        assert services[name]["depends_on"]["postgres"]["condition"] == "service_healthy"
    pg_volumes = {v.split(":")[0] for v in pg["volumes"]}
    app_volumes = {v.split(":")[0] for n in ("api", "worker") for v in services[n]["volumes"]}
    assert pg_volumes.isdisjoint(app_volumes)  # the database is not on the shared data volume


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


def test_kubernetes_registry_is_postgres_from_a_secret_and_the_rwx_volume_holds_artifacts() -> None:
    k8s = ROOT / "deploy" / "k8s"
    kustom = yaml.safe_load((k8s / "kustomization.yaml").read_text())
    docs = [d for f in kustom["resources"] for d in load_all(k8s / f)]
    pg = next(d for d in docs if d["kind"] == "StatefulSet")
    assert pg["metadata"]["name"] == "gridplace-postgres"
    claim = pg["spec"]["volumeClaimTemplates"][0]["spec"]
    assert claim["accessModes"] == ["ReadWriteOnce"]  # the database's own volume, not RWX
    assert ("Service", "gridplace-postgres") in {(d["kind"], d["metadata"]["name"]) for d in docs}
    config = next(d for d in docs if d["kind"] == "ConfigMap")["data"]
    assert "GRIDPLACE_REGISTRY_JOURNAL_MODE" not in config
    assert "GRIDPLACE_REGISTRY_URL" not in config  # holds a password: a Secret
    for name in ("gridplace-api", "gridplace-worker"):
        dep = next(d for d in docs if d["kind"] == "Deployment" and d["metadata"]["name"] == name)
        env = {e["name"]: e for e in dep["spec"]["template"]["spec"]["containers"][0]["env"]}
        ref = env["GRIDPLACE_REGISTRY_URL"]["valueFrom"]["secretKeyRef"]
        assert ref == {"name": "gridplace-registry", "key": "url"}
    readme = (ROOT / "deploy" / "README.md").read_text()
    assert "gridplace-registry" in readme and "ReadWriteMany" in readme
    for env_name in SETTINGS_ENV:  # every setting is in the README's table
        assert f"`{env_name}`" in readme or env_name in readme, env_name


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
    stages = re.findall(r"^FROM\s+(\S+)", text, re.MULTILINE)
    assert len(set(stages)) == 1, f"the venv copied between stages needs the same Python: {stages}"
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
