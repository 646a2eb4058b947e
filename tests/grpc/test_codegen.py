"""The committed gRPC stubs are exactly what ``protos/`` generates (drift cannot land)."""

from __future__ import annotations

import shutil
from pathlib import Path

from service.grpc import codegen


def test_committed_stubs_match_the_protos() -> None:
    assert codegen.check() == [], "run: python -m service.grpc.codegen"


def test_a_changed_proto_is_detected(tmp_path: Path) -> None:
    protos = tmp_path / "protos"
    shutil.copytree(codegen.PROTOS, protos)
    proto = protos / "gridplace" / "v1" / "localization.proto"
    proto.write_text(proto.read_text().replace("uint32 dimension = 4;",
                                               "uint32 dimension = 4;\n  string extra = 99;"))  # fmt: skip
    assert codegen.check(protos=protos) == [
        "localization_pb2.py: differs from what the .proto generates",
        "localization_pb2.pyi: differs from what the .proto generates",
    ]


def test_stale_and_missing_stubs_are_reported(tmp_path: Path) -> None:
    gen = tmp_path / "gen"
    gen.mkdir()
    for path in codegen.GEN.glob("*_pb2*"):
        shutil.copy(path, gen / path.name)
    (gen / "localization_pb2_grpc.py").unlink()
    (gen / "old_pb2.py").write_text("")
    assert codegen.check(gen=gen) == ["localization_pb2_grpc.py: missing",
                                      "old_pb2.py: no .proto generates it"]  # fmt: skip
    assert codegen.write(gen=gen) and codegen.check(gen=gen) == []
    assert not (gen / "old_pb2.py").exists()


def test_version_stamps_alone_are_not_drift() -> None:
    code = (codegen.GEN / "localization_pb2_grpc.py").read_bytes()
    bumped = code.replace(b"GRPC_GENERATED_VERSION = '", b"GRPC_GENERATED_VERSION = '9")
    assert bumped != code and codegen.normalise(bumped) == codegen.normalise(code)
