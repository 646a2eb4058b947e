"""Route uploads of several traversals (repeated 'file' fields, optional 'places' files)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from api_helpers import npy_bytes
from fastapi.testclient import TestClient

from service.core.traversal_upload import store_traversals
from service.encoding.traversals import as_traversals


def _post(client: TestClient, auth: dict[str, str], name: str, files: list[tuple[str, str, bytes]],
          **data: str):  # fmt: skip
    return client.post(f"/v1/maps/{name}/routes", headers=auth,
                       files=[(field, (fname, payload)) for field, fname, payload in files],
                       data={"trainer": "ridge", **data})  # fmt: skip


def test_two_frame_aligned_traversals_train_one_version(client, auth, route, backend) -> None:
    ref, query = route
    r = _post(client, auth, "m", [("file", "summer.npy", npy_bytes(ref)),
                                  ("file", "winter.npy", npy_bytes(query))])  # fmt: skip
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["state"] == "succeeded", job
    version = client.get(f"/v1/maps/m/versions/{job['version']}", headers=auth).json()
    assert version["n_traversals"] == 2 and version["n_frames"] == ref.shape[0]
    _, path, _, _ = backend.submitted[0]
    np.testing.assert_array_equal(np.load(path), np.concatenate([ref, query]))
    client.app.state.context.store.refresh()  # type: ignore[attr-defined]
    res = client.post("/v1/localize", json={"map": "m", "descriptor": query[7].tolist()})
    assert res.status_code == 200 and 0 <= res.json()["index"] < ref.shape[0]


def test_traversals_with_place_indices(client, auth, route, settings) -> None:
    ref, query = route
    keep = np.arange(0, ref.shape[0], 3)
    r = _post(client, auth, "m", [
        ("file", "summer.npy", npy_bytes(ref)), ("file", "winter.npy", npy_bytes(query[keep])),
        ("places", "summer_places.npy", npy_bytes(np.arange(ref.shape[0]))),
        ("places", "winter_places.npy", npy_bytes(keep)),
    ], n_chunks="2")  # fmt: skip
    assert r.status_code == 202, r.text
    version = client.get(f"/v1/maps/m/versions/{r.json()['version']}", headers=auth).json()
    assert version["n_traversals"] == 2 and version["n_frames"] == ref.shape[0]
    stored = sorted(settings.data_dir.glob("uploads/*.npy"))
    assert len(stored) == 2  # the stacked descriptors and their place index
    places = next(np.load(p) for p in stored if np.load(p).ndim == 1)
    np.testing.assert_array_equal(places, np.concatenate([np.arange(ref.shape[0]), keep]))


def _float_npy() -> bytes:
    return npy_bytes(np.arange(10.0))


BAD = [
    ("widths", lambda r, q: [("file", "a.npy", npy_bytes(r)),
                             ("file", "b.npy", npy_bytes(q[:, :20]))],
     400, "traversal 2 ('b.npy') has 20 columns but traversal 1 ('a.npy') has 32"),
    ("lengths", lambda r, q: [("file", "a.npy", npy_bytes(r)),
                              ("file", "b.npy", npy_bytes(q[:50]))],
     400, "traversal 2 ('b.npy') has 50 rows but traversal 1 ('a.npy') has 120"),
    ("places count", lambda r, q: [("file", "a.npy", npy_bytes(r)), ("file", "b.npy", npy_bytes(q)),
                                   ("places", "p.npy", npy_bytes(np.arange(120)))],
     400, "2 route file(s) need 2 'places' file(s)"),
    ("places length", lambda r, q: [("file", "a.npy", npy_bytes(r)),
                                    ("places", "p.npy", npy_bytes(np.arange(100)))],
     400, "'p.npy' has shape [100] but its traversal has 120 rows"),
    ("places dtype", lambda r, q: [("file", "a.npy", npy_bytes(r[:10])),
                                   ("places", "p.npy", _float_npy())],
     400, "must hold integers"),
    ("missing place", lambda r, q: [("file", "a.npy", npy_bytes(r)),
                                    ("places", "p.npy", npy_bytes(np.arange(120) // 2 * 2))],
     400, "have no row"),
    ("places not npy", lambda r, q: [("file", "a.npy", npy_bytes(r)),
                                     ("places", "p.npy", b"hello")],
     400, "not a .npy"),
    ("nan in traversal 2", lambda r, q: [("file", "a.npy", npy_bytes(r)),
                                         ("file", "b.npy", npy_bytes(np.full_like(q, np.nan)))],
     400, "NaN"),
    ("chunks for the places", lambda r, q: [("file", "a.npy", npy_bytes(r[:6])),
                                            ("file", "b.npy", npy_bytes(q[:6]))],
     400, "n_chunks"),
    ("unknown file field", lambda r, q: [("file", "a.npy", npy_bytes(r)),
                                         ("index", "p.npy", npy_bytes(np.arange(120)))],
     422, "unexpected file field"),
]  # fmt: skip


@pytest.mark.parametrize("case", BAD, ids=[c[0] for c in BAD])
def test_bad_traversal_uploads_are_4xx_naming_the_problem(client, auth, route, settings,
                                                          case) -> None:  # fmt: skip
    label, files, status, message = case
    data = {"n_chunks": "4"} if label == "chunks for the places" else {}
    r = _post(client, auth, "m", files(*route), **data)
    assert r.status_code == status, r.text
    assert message in r.json()["message"], r.text
    assert not list(settings.data_dir.glob("uploads/*.npy"))  # nothing half-written


def test_the_content_hash_covers_every_file(tmp_path: Path, route) -> None:
    ref, query = route
    one = store_traversals(tmp_path, as_traversals(np.concatenate([ref, query])), "npy")
    two = store_traversals(tmp_path, as_traversals([ref, query]), "npy")
    swapped = store_traversals(tmp_path, as_traversals([query, ref]), "npy")
    n = ref.shape[0]
    perm = np.random.default_rng(0).permutation(n)
    indexed = store_traversals(
        tmp_path, as_traversals([ref, query[perm]], places=[np.arange(n), perm]), "npy"
    )
    hashes = {one.content_sha256, two.content_sha256, swapped.content_sha256,
              indexed.content_sha256}  # fmt: skip
    assert len(hashes) == 4
    assert one.places is None and one.n_traversals == 1
    assert two.n_traversals == 2 and two.places is not None
    again = store_traversals(tmp_path, as_traversals([ref, query]), "npy")
    assert again.content_sha256 == two.content_sha256


def test_a_single_file_upload_is_stored_as_before(client, auth, route, backend, settings) -> None:
    r = _post(client, auth, "m", [("file", "r.npy", npy_bytes(route[0]))])
    assert r.status_code == 202, r.text
    assert len(list(settings.data_dir.glob("uploads/*.npy"))) == 1
    version = client.get("/v1/maps/m/versions/1", headers=auth).json()
    assert version["n_traversals"] == 1
