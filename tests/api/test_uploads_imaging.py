"""Route archives (ordering, bombs, corrupt members) and the image extractors."""

from __future__ import annotations

import io
import tarfile
import zipfile

import numpy as np
import pytest
from api_helpers import png_bytes

from service.core.uploads import parse_route, store_descriptors
from service.errors import (
    EmptyInputError,
    InvalidInputError,
    InvalidParameterError,
    PayloadTooLargeError,
    UnsafeFileError,
)
from service.imaging import decode_image, make_extractor, parse_extractor_config

SMALL = {"kind": "patchnorm", "width": 32, "height": 16, "patch": 8}
MiB = 1024 * 1024


def _parse(name: str, data: bytes, limit: int = 4 * MiB) -> tuple[np.ndarray, str]:
    return parse_route(name, io.BytesIO(data), limit, lambda: make_extractor(SMALL))


def _tar(members: dict[str, bytes], mode: str = "w:gz") -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode=mode) as tf:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    return buf.getvalue()


def test_archives_are_read_in_file_name_order() -> None:
    frames = {f"r/f{i:02d}.png": png_bytes(i) for i in (5, 1, 3, 2, 4)}
    ext = make_extractor(SMALL)
    want = ext.extract([decode_image(png_bytes(i)) for i in (1, 2, 3, 4, 5)])
    zbuf = io.BytesIO()
    with zipfile.ZipFile(zbuf, "w") as zf:
        for name, data in frames.items():
            zf.writestr(name, data)
        zf.writestr("r/README.txt", b"ignored: not an image")
    for blob, name in ((zbuf.getvalue(), "r.zip"), (_tar(frames), "r.tar.gz"), (_tar(frames, "w"), "r.tar")):
        X, kind = _parse(name, blob)
        assert kind == "images"
        np.testing.assert_allclose(X, want)


def test_bombs_and_limits() -> None:
    zbuf = io.BytesIO()
    with zipfile.ZipFile(zbuf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("a.png", png_bytes(0))
        zf.writestr("b.png", b"\x00" * (2 * MiB))  # ~2 KiB compressed: ratio ≈ 1000
    with pytest.raises(PayloadTooLargeError, match="decompression bomb|upload limit"):
        _parse("b.zip", zbuf.getvalue(), limit=MiB)
    with pytest.raises(PayloadTooLargeError, match="decompression bomb"):
        _parse("b.zip", zbuf.getvalue(), limit=100 * MiB)
    big = _tar({"a.png": png_bytes(0), "b.png": b"\x01" * (2 * MiB)})
    with pytest.raises(PayloadTooLargeError, match="upload limit"):
        _parse("b.tar.gz", big, limit=MiB)


def test_malformed_archives_and_members() -> None:
    with pytest.raises(EmptyInputError, match="no image"):
        _parse("e.tar", _tar({"notes.txt": b"x"}, "w"))
    with pytest.raises(InvalidInputError, match="not a decodable image"):
        _parse("c.tar", _tar({"a.png": png_bytes(0), "b.png": b"garbage"}, "w"))
    with pytest.raises(UnsafeFileError):
        _parse("t.zip", b"PK\x03\x04" + b"\x00" * 40)
    with pytest.raises(UnsafeFileError, match="neither"):
        _parse("x.bin", b"\x00\x01\x02")


def test_store_is_content_addressed_and_atomic(tmp_path) -> None:
    X = np.arange(12, dtype=np.float32).reshape(3, 4)
    a = store_descriptors(tmp_path, X, "npy")
    b = store_descriptors(tmp_path, X, "npy")
    assert a.path == b.path and a.path.name == f"{a.sha256}.npy"
    assert not [p for p in (tmp_path / "uploads").iterdir() if p.name.startswith(".")]
    np.testing.assert_array_equal(np.load(a.path, allow_pickle=False), X)


def test_extractor_configs_validate_and_describe_their_size() -> None:
    assert parse_extractor_config(None).kind == "cnn"  # the default: see service/imaging/config.py
    assert parse_extractor_config({"kind": "patchnorm"}).model_dump() == {
        "kind": "patchnorm", "width": 64, "height": 32, "patch": 16}  # fmt: skip
    with pytest.raises(InvalidParameterError, match="multiples of patch"):
        parse_extractor_config({"kind": "patchnorm", "width": 60})
    with pytest.raises(InvalidParameterError, match="kind"):
        parse_extractor_config({"kind": "sift"})
    hog = make_extractor({"kind": "hog", "width": 64, "height": 32})
    out = hog.extract([decode_image(png_bytes(1)), decode_image(png_bytes(2))])
    assert out.shape == (2, hog.n_features) and out.dtype == np.float32


def test_decode_refuses_non_images() -> None:
    with pytest.raises(EmptyInputError):
        decode_image(b"")
    with pytest.raises(InvalidInputError, match="not a decodable image"):
        decode_image(b"%PDF-1.4 not an image")
    with pytest.raises(InvalidInputError, match="truncated or corrupt"):
        decode_image(png_bytes(3)[:60])
