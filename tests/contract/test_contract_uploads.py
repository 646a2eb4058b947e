"""Everything that can be checked from a route upload is checked before the 202 (real
server process)."""

from __future__ import annotations

import io
import zipfile

import httpx
import numpy as np
import pytest
from contract_helpers import AUTH, D, N

pytestmark = pytest.mark.slow


def _npy(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


def _upload(api: httpx.Client, payload: bytes, **form: str) -> httpx.Response:
    return api.post("/v1/maps/checked/routes", headers=AUTH,
                    files={"file": ("r.npy", payload)}, data={"trainer": "ridge", **form})  # fmt: skip


@pytest.mark.parametrize(("form", "status", "needle"), [
    ({"periods": "5,5"}, 400, "smaller than the number of frames"),  # 25 < 160 frames
    ({"periods": ",".join(["2"] * 20)}, 400, "never"),  # 2^19 ≥ 160: the leading digits are constant
    ({"periods": ",".join(["2"] * 5000)}, 422, "periods"),
    ({"periods": f"2,{10**12}"}, 422, "periods"),
    ({"periods": "200,2"}, 400, "longer than"),  # 200 > 160 frames: empty classes, wasted storage
    ({"n_chunks": "4", "periods": "41"}, 400, "chunk"),  # chunks of 40 frames: 41 > 40
    ({"n_chunks": "4", "periods": "5,5"}, 400, "smaller than"),  # 25 < 40 frames per chunk
    ({"n_patterns": "9"}, 400, "too many"),  # 160 frames carry at most 8 binary digits
    ({"n_chunks": "100"}, 400, "n_chunks"),
    ({"random_state": "-5"}, 422, "random_state"),
    ({"random_state": str(2**32)}, 422, "random_state"),
    ({"gamma": "1e400"}, 422, "gamma"),
    ({"C": "inf"}, 422, "C"),
])  # fmt: skip
def test_everything_checkable_from_the_upload_is_checked_before_202(
    api: httpx.Client, contract_route: tuple[np.ndarray, np.ndarray], form: dict[str, str],
    status: int, needle: str,
) -> None:
    r = _upload(api, _npy(contract_route[0]), **form)
    assert r.status_code == status, (form, r.text)
    assert needle.lower() in r.json()["message"].lower(), r.text


def test_a_declared_shape_is_checked_before_the_data_is_read(api: httpx.Client) -> None:
    X = np.zeros((N, D), np.float32)
    X[-1, 0] = np.nan  # found only by reading the data
    r = _upload(api, _npy(X), periods="5,5")
    assert r.status_code == 400, r.text
    assert "smaller than the number of frames 160" in r.json()["message"]  # shape from the header


def test_an_image_archive_is_checked_from_its_image_count_before_decoding(api: httpx.Client) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for i in range(4):
            zf.writestr(f"frame-{i}.png", b"not decoded: refused before")
    r = api.post("/v1/maps/checked/routes", headers=AUTH, files={"file": ("r.zip", buf.getvalue())},
                 data={"trainer": "ridge", "periods": "3", "extractor": "patchnorm",
                       "width": "32", "height": "16", "patch": "8"})  # fmt: skip
    assert r.status_code == 400, r.text
    assert "smaller than the number of frames 4" in r.json()["message"]
