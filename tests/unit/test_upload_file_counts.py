"""How a route upload and a traversal append count their files: the client refuses a
mismatch before sending, the server names the form's files; both share one rule each."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from service.client import calls
from service.core.traversal_upload import UploadedFile, check_file_counts
from service.errors import EmptyInputError, InvalidInputError


def _upload(name: str) -> UploadedFile:
    return UploadedFile(name, io.BytesIO(b""))


@pytest.mark.parametrize("what", ["route", "traversal"])
def test_the_server_names_missing_files_and_a_places_count_that_does_not_match(what: str) -> None:
    with pytest.raises(InvalidInputError, match=f"send the {what} as one or more 'file' fields"):
        check_file_counts([], [], what)
    with pytest.raises(InvalidInputError, match=f"2 {what} file\\(s\\) need 2 'places' file\\(s\\) "
                       r"\(one per file, in the same order\), got 1") as err:  # fmt: skip
        check_file_counts([_upload("a.npy"), _upload("b.npy")], [_upload("p.npy")], what)
    assert err.value.details == {"files": 2, "places": 1}
    check_file_counts([_upload("a.npy")], [], what)  # no places: any number of files
    check_file_counts([_upload("a.npy")], [_upload("p.npy")], what)


def test_the_client_refuses_a_places_count_that_does_not_match_before_sending() -> None:
    X = np.zeros((4, 3), dtype=np.float32)
    options = calls.options_of(None, {"trainer": "ridge"})
    with pytest.raises(EmptyInputError, match="upload_route needs at least one route file"):
        calls.upload_route("m", [], options, None, None)
    with pytest.raises(InvalidInputError, match=r"2 route file\(s\) need 2 place-index file\(s\) "
                       r"\(one per file, in the same order\), got 1"):  # fmt: skip
        calls.upload_route("m", [X, X], options, None, None, places=[np.arange(4)])
    append = calls.append_options([], extend=False, whiten=None, activate=False)
    with pytest.raises(EmptyInputError, match="append_traversals needs at least one traversal"):
        calls.append_traversals("m", 1, [], append)
    with pytest.raises(InvalidInputError, match=r"2 traversal\(s\) need 2 place-index file\(s\) "
                       r"\(one per traversal, in the same order\), got 3"):  # fmt: skip
        calls.append_traversals("m", 1, [X, X], append, places=[np.arange(4)] * 3)


def test_the_client_names_each_part_and_closes_what_it_opened_when_a_part_fails(
    tmp_path: Path,
) -> None:
    X = np.zeros((4, 3), dtype=np.float32)
    options = calls.options_of(None, {"trainer": "ridge"})
    one = calls.upload_route("m", X, options, None, "given.npy")
    assert [(k, v[0]) for k, v in one.kwargs["files"]] == [("file", "given.npy")]
    two = calls.upload_route("m", [X, X], options, None, "ignored.npy", places=[np.arange(4)] * 2)
    assert [(k, v[0]) for k, v in two.kwargs["files"]] == [
        ("file", "route-1.npy"), ("file", "route-2.npy"),
        ("places", "places-1.npy"), ("places", "places-2.npy"),
    ]  # fmt: skip
    named = calls.upload_route("m", [X, X], options, None, None, names=["s.npy", None])
    assert [v[0] for _, v in named.kwargs["files"]] == ["s.npy", "route-2.npy"]
    path = tmp_path / "winter.npy"
    np.save(path, X)
    append = calls.append_options([], extend=False, whiten=None, activate=False)
    sent = calls.append_traversals("m", 1, [X, path], append)
    assert [v[0] for _, v in sent.kwargs["files"]] == ["traversal-1.npy", "winter.npy"]
    assert len(sent.files) == 1 and not sent.files[0].closed
    sent.close()
    assert sent.files[0].closed
    opened: list[object] = []
    real_open = Path.open

    def tracking_open(self: Path, *args: object, **kwargs: object) -> object:
        fh = real_open(self, *args, **kwargs)  # type: ignore[arg-type]
        opened.append(fh)
        return fh

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Path, "open", tracking_open)
        with pytest.raises(InvalidInputError, match="route file not found"):
            calls.append_traversals("m", 1, [path, tmp_path / "missing.npy"], append)
    assert len(opened) == 1 and opened[0].closed  # type: ignore[attr-defined]
