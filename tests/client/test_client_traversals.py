"""Several traversals through the client and ``gridplace client upload`` against the real
server of conftest.py (SYNTHETIC data, ridge)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest
from client_helpers import TOKEN, N
from typer.testing import CliRunner

from service.api.process import ServerProcess
from service.cli import app
from service.client import AsyncGridplaceClient, GridplaceClient
from service.errors import DimensionMismatchError, InvalidInputError

Route = tuple[np.ndarray, np.ndarray]


def test_upload_two_traversals_and_see_them_in_the_version(gp: GridplaceClient,
                                                           route: Route) -> None:  # fmt: skip
    job = gp.upload_route("two", [route[0], route[1]], trainer="ridge")
    done = gp.wait_for_job(job.id, timeout=90, poll_interval=0.05)
    assert done.state == "succeeded", done.error
    version = gp.get_version("two", done.version or 0)
    assert version.n_traversals == 2 and version.n_frames == N


def test_upload_traversals_with_place_indices(gp: GridplaceClient, route: Route,
                                              tmp_path: Path) -> None:  # fmt: skip
    keep = np.arange(0, N, 4)
    np.save(tmp_path / "winter.npy", route[1][keep])
    np.save(tmp_path / "winter_places.npy", keep)
    job = gp.upload_route("indexed", [route[0], tmp_path / "winter.npy"], trainer="ridge",
                          places=[np.arange(N), tmp_path / "winter_places.npy"])  # fmt: skip
    done = gp.wait_for_job(job.id, timeout=90, poll_interval=0.05)
    assert done.state == "succeeded", done.error
    assert gp.get_version("indexed", done.version or 0).n_traversals == 2


def test_bad_traversals_come_back_as_the_servers_4xx(gp: GridplaceClient, route: Route) -> None:
    with pytest.raises(DimensionMismatchError, match="has 40 columns but traversal 1"):
        gp.upload_route("bad-trav", [route[0], route[1][:, :40]], trainer="ridge")
    with pytest.raises(DimensionMismatchError, match="has 10 rows but traversal 1"):
        gp.upload_route("bad-trav", [route[0], route[1][:10]], trainer="ridge")
    with pytest.raises(InvalidInputError, match="need 2 place-index file"):  # before sending
        gp.upload_route("bad-trav", [route[0], route[1]], places=[np.arange(N)])


def test_async_client_uploads_traversals(server: ServerProcess, route: Route,
                                         tmp_path: Path) -> None:  # fmt: skip
    path = tmp_path / "winter.npy"
    np.save(path, route[1])

    async def main() -> None:
        async with AsyncGridplaceClient(server.url, token=TOKEN) as agp:
            job = await agp.upload_route("async-two", [route[0], path], trainer="ridge")
            done = await agp.wait_for_job(job.id, timeout=90, poll_interval=0.05)
            assert done.state == "succeeded", done.error
            assert (await agp.get_version("async-two", 1)).n_traversals == 2

    asyncio.run(main())


def test_cli_client_upload_of_two_files(server: ServerProcess, route: Route,
                                        tmp_path: Path) -> None:  # fmt: skip
    np.save(tmp_path / "a.npy", route[0])
    np.save(tmp_path / "b.npy", route[1])
    env = {"GRIDPLACE_URL": server.url, "GRIDPLACE_ADMIN_TOKEN": TOKEN, "COLUMNS": "200"}
    r = CliRunner().invoke(app, ["client", "upload", "cli-two", str(tmp_path / "a.npy"),
                                 str(tmp_path / "b.npy"), "--trainer", "ridge", "--wait",
                                 "--json"], env=env)  # fmt: skip
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["state"] == "succeeded"
    r = CliRunner().invoke(app, ["client", "versions", "cli-two", "--json"], env=env)
    assert r.exit_code == 0 and json.loads(r.output)[0]["n_traversals"] == 2
    np.save(tmp_path / "narrow.npy", route[1][:, :40])
    r = CliRunner().invoke(app, ["client", "upload", "cli-two", str(tmp_path / "a.npy"),
                                 str(tmp_path / "narrow.npy"), "--trainer", "ridge"], env=env)  # fmt: skip
    assert r.exit_code == 2 and "narrow.npy" in r.output and "columns" in r.output
