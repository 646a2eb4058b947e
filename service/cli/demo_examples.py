"""The copy-paste examples ``gridplace demo`` prints once its server answers."""

from __future__ import annotations

import base64
import json
import re
import shlex
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.rule import Rule

import service

GRPC_SERVICE = "gridplace.v1.Localization"
# the job id out of an upload's JSON answer, with nothing but Python (jq may be missing)
JSON_ID = """python3 -c 'import json, sys; print(json.load(sys.stdin)["id"])'"""
PROTOS_DIR = Path(service.__file__).resolve().parent.parent / "protos"


def _q(path: Path | str) -> str:
    return shlex.quote(str(path))


def _proto_flags() -> str:
    """``-import-path/-proto`` for grpcurl when the protos ship with this checkout (else the
    server's reflection service is used)."""
    protos = sorted(PROTOS_DIR.rglob("*.proto")) if PROTOS_DIR.is_dir() else []
    if not protos:
        return ""
    files = " ".join(f"-proto {_q(p.relative_to(PROTOS_DIR))}" for p in protos)
    return f"-import-path {_q(PROTOS_DIR)} {files} "


_FIELD = re.compile(r"^\s*(repeated\s+)?(\w+)\s+(\w+)\s*=\s*\d+", re.MULTILINE)


def request_fields(protos_dir: Path, message: str = "LocalizeRequest") -> dict[str, str]:
    """``field name → type`` of ``message`` in the shipped protos (empty if none is found)."""
    files = sorted(protos_dir.rglob("*.proto")) if protos_dir.is_dir() else []
    for proto in files:
        text = proto.read_text(errors="replace")
        match = re.search(rf"message\s+{message}\s*\{{(.*?)\n\}}", text, re.DOTALL)
        if match:
            return {name: f"{'repeated ' if rep else ''}{typ}"
                    for rep, typ, name in _FIELD.findall(match.group(1))}  # fmt: skip
    return {}


def localize_body(descriptor: np.ndarray, fields: dict[str, str]) -> dict[str, object]:
    """A proto3-JSON ``Localize`` request for ``descriptor``: a repeated float field gets the
    numbers, a bytes field base64 float32 (the default without protos: ``descriptor`` floats)."""
    vec = np.ascontiguousarray(descriptor, dtype="<f4").ravel()
    name = next((f for f in fields if "descriptor" in f), "descriptor")
    value: object = [round(float(v), 6) for v in vec]
    if fields.get(name) == "bytes":
        value = base64.b64encode(vec.tobytes()).decode("ascii")
    map_field = next((f for f in fields if f in ("map", "map_name", "name")), "map")
    return {map_field: "demo", name: value}


def grpc_request(data_dir: Path, descriptor: np.ndarray) -> Path:
    """The grpcurl request body file for ``Localize``."""
    path = data_dir / "demo-grpc-localize.json"
    path.write_text(json.dumps(localize_body(descriptor, request_fields(PROTOS_DIR))))
    return path


def print_examples(
    console: Console,
    url: str,
    token: str,
    grpc_port: int,
    data_dir: Path,
    probe: int,
    descriptor: np.ndarray,
    query_image: Path | None,
    log_path: Path,
    answer: int | None = None,
) -> None:
    auth = '-H "Authorization: Bearer $GRIDPLACE_ADMIN_TOKEN"'
    request = data_dir / "demo-localize.json"
    queries = data_dir / "demo-queries.npy"
    raw = data_dir / "demo-queries.f32"
    lines = [
        f"export GRIDPLACE_URL={url}",
        f"export GRIDPLACE_ADMIN_TOKEN={token}",
        "",
        f"# localize winter frame {probe}: its descriptor as base64 little-endian float32"
        + (f" (the server answered frame {answer} above)" if answer is not None else ""),
        f"curl -s -H 'content-type: application/json' -d @{_q(request)} $GRIDPLACE_URL/v1/localize",
    ]
    if query_image is not None:
        lines += ["# the same place from the camera image (the map stores its extractor)",
                  f"curl -s -F map=demo -F image=@{_q(query_image)} $GRIDPLACE_URL/v1/localize"]  # fmt: skip
    lines += [
        "# 100 winter frames in one binary request (raw little-endian float32, row after row)",
        (
            f"curl -s -H 'content-type: application/octet-stream' --data-binary @{_q(raw)} "
            f'"$GRIDPLACE_URL/v1/localize/batch?map=demo&d={descriptor.size}"'
        ),
        "# maps and versions (admin)",
        f"curl -s {auth} $GRIDPLACE_URL/v1/maps",
        f"curl -s {auth} $GRIDPLACE_URL/v1/maps/demo/versions",
        "# upload a route: trains a new map in the background (202 + the job); then follow the job",
        (
            f"JOB_ID=$(curl -s {auth} -F file=@{_q(queries)} -F trainer=ridge "
            f"$GRIDPLACE_URL/v1/maps/demo-small/routes | {JSON_ID}) && echo $JOB_ID"
        ),
        f"curl -s {auth} $GRIDPLACE_URL/v1/jobs/$JOB_ID",
        "",
        "# the same with the Python client's CLI (reads GRIDPLACE_URL / GRIDPLACE_ADMIN_TOKEN)",
        "gridplace client status",
        f"gridplace client localize demo --npy {_q(queries)} --rows 0:5",
        "gridplace client maps && gridplace client versions demo",
        f"gridplace client upload demo-small {_q(queries)} --trainer ridge --wait",
        "gridplace client activate demo 1",
    ]
    host = url.split("://", 1)[-1].rsplit(":", 1)[0]
    if grpc_port:
        body = grpc_request(data_dir, descriptor)
        flags = _proto_flags()
        lines += [
            "",
            f"# gRPC on {host}:{grpc_port} (service {GRPC_SERVICE})",
            f"grpcurl -plaintext {flags}-d @ {host}:{grpc_port} {GRPC_SERVICE}/Localize < {_q(body)}",
            f'grpcurl -plaintext {flags}-H "authorization: Bearer $GRIDPLACE_ADMIN_TOKEN" '
            f"-d '{{}}' {host}:{grpc_port} {GRPC_SERVICE}/ListMaps",
        ]
    else:
        lines += [
            "",
            "# gRPC is not served by this build (no service.grpc module or --grpc-port 0)",
        ]
    console.print(Rule("try it (copy and paste into another shell)"))
    console.print("\n".join(lines), markup=False, highlight=False, soft_wrap=True)
    console.print(Rule())
    console.print(f"API docs: {url}/docs   server log: {log_path}   Ctrl-C stops the server",
                  markup=False, highlight=False, soft_wrap=True)  # fmt: skip
