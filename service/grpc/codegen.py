"""Generate (or check) the committed Python gRPC stubs from ``protos/``.

``python -m service.grpc.codegen`` rewrites ``service/grpc/gen/*_pb2*.py(i)`` with
grpcio-tools' protoc; ``--check`` regenerates into memory and fails when anything differs
from what is committed (``tests/grpc/test_codegen.py`` runs the check, so a ``.proto`` change
without regenerated stubs cannot land).

The protos keep their canonical names (``gridplace/v1/localization.proto``: what reflection
shows and what other languages import), and the stubs live flat in ``service.grpc.gen``: the
one generated absolute import (``from gridplace.v1 import x_pb2``) is rewritten to the package.
The generator's own version stamps are ignored by the check, so a patch release of
grpcio-tools does not fail it while any change to the API itself does.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from importlib import resources
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PROTOS = ROOT / "protos"
PROTO_PACKAGE = "gridplace/v1"
GEN = Path(__file__).resolve().parent / "gen"
GEN_MODULE = "service.grpc.gen"
SUFFIXES = ("_pb2.py", "_pb2.pyi", "_pb2_grpc.py")

# lines that only stamp the generator's version
_STAMPS = (
    re.compile(rb"^# Protobuf Python Version: .*$", re.MULTILINE),
    re.compile(rb"^GRPC_GENERATED_VERSION = .*$", re.MULTILINE),
    re.compile(rb"_runtime_version\.ValidateProtobufRuntimeVersion\([^)]*\)", re.DOTALL),
)


def proto_files(protos: Path = PROTOS) -> list[Path]:
    files = sorted((protos / PROTO_PACKAGE).glob("*.proto"))
    if not files:
        raise FileNotFoundError(f"no .proto files under {protos / PROTO_PACKAGE}")
    return files


def generate(protos: Path = PROTOS) -> dict[str, bytes]:
    """File name → content of every stub generated from ``protos``."""
    from grpc_tools import protoc

    well_known = str(resources.files("grpc_tools") / "_proto")
    rel = [str(p.relative_to(protos)) for p in proto_files(protos)]
    with tempfile.TemporaryDirectory(prefix="gridplace-codegen-") as tmp:
        args = ["protoc", f"-I{protos}", f"-I{well_known}", f"--python_out={tmp}",
                f"--pyi_out={tmp}", f"--grpc_python_out={tmp}", *rel]  # fmt: skip
        if protoc.main(args) != 0:
            raise RuntimeError(f"protoc failed on {rel}")
        out: dict[str, bytes] = {}
        for path in sorted((Path(tmp) / PROTO_PACKAGE).iterdir()):
            if path.name.endswith(SUFFIXES):
                out[path.name] = _relocate(path.read_bytes())
    return out


def _relocate(code: bytes) -> bytes:
    pkg = PROTO_PACKAGE.replace("/", ".").encode()
    return re.sub(rb"^from " + re.escape(pkg) + rb" import ", b"from " + GEN_MODULE.encode()
                  + b" import ", code, flags=re.MULTILINE)  # fmt: skip


def normalise(code: bytes) -> bytes:
    """``code`` without the generator's version stamps."""
    for pattern in _STAMPS:
        code = pattern.sub(b"<generator version>", code)
    return code


def write(gen: Path = GEN, protos: Path = PROTOS) -> list[Path]:
    files = generate(protos)
    for stale in gen.glob("*_pb2*"):
        if stale.name not in files:
            stale.unlink()
    written = []
    for name, code in files.items():
        (gen / name).write_bytes(code)
        written.append(gen / name)
    return written


def check(gen: Path = GEN, protos: Path = PROTOS) -> list[str]:
    """Problems with the committed stubs (empty when they match the protos)."""
    fresh = generate(protos)
    committed = {p.name: p.read_bytes() for p in gen.glob("*_pb2*") if p.name.endswith(SUFFIXES)}
    problems = [f"{name}: missing" for name in sorted(set(fresh) - set(committed))]
    problems += [f"{name}: no .proto generates it" for name in sorted(set(committed) - set(fresh))]
    problems += [f"{name}: differs from what the .proto generates"
                 for name in sorted(set(fresh) & set(committed))
                 if normalise(fresh[name]) != normalise(committed[name])]  # fmt: skip
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="fail if the stubs are stale")
    args = parser.parse_args(argv)
    if args.check:
        problems = check()
        for p in problems:
            print(f"stale gRPC stub {p}; run: python -m service.grpc.codegen", file=sys.stderr)
        return 1 if problems else 0
    for path in write():
        print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
