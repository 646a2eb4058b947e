"""Crash safety, corruption detection, the generation counter and multi-process publishing.
Models are trained on SYNTHETIC routes (see conftest)."""

from __future__ import annotations

import multiprocessing as mp
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from service.encoding import PlaceRecognizer
from service.errors import ArtifactError, NotFoundError
from service.registry import Registry
from service.registry.db import JournalMode

from registry_pg import empty_database


def test_corrupt_tensors_are_detected_on_load(registry, publish, model):
    publish(model)
    tensors = registry.artifact_dir("route-a", 1) / "tensors.safetensors"
    data = bytearray(tensors.read_bytes())
    data[-1] ^= 0xFF
    tensors.write_bytes(bytes(data))
    with pytest.raises(ArtifactError, match="checksum"):
        registry.load_model("route-a", 1)


def test_a_replaced_artifact_is_detected_on_load(tmp_path, registry, publish, model, other_model):
    from service.encoding import save_model

    publish(model)
    path = registry.artifact_dir("route-a", 1)
    os.rename(path, tmp_path / "old")
    save_model(other_model, path)  # self-consistent, but not what was published
    with pytest.raises(ArtifactError, match="does not match"):
        registry.load_model("route-a", 1)


def test_missing_artifact_is_an_artifact_error(registry, publish, model):
    import shutil

    publish(model)
    shutil.rmtree(registry.artifact_dir("route-a", 1))
    with pytest.raises(ArtifactError):
        registry.load_model("route-a", 1)


def test_failure_between_artifact_and_commit_leaves_no_version(
    registry, publish, model, monkeypatch
):
    def boom(*args: object, **kwargs: object) -> None:
        raise RuntimeError("simulated failure before the metadata transaction")

    monkeypatch.setattr(Registry, "_commit_version", boom)
    gen = registry.generation()
    with pytest.raises(RuntimeError):
        publish(model)
    monkeypatch.undo()
    assert registry.generation() == gen
    with pytest.raises(NotFoundError):
        registry.get_map("route-a")
    assert not registry.artifact_dir("route-a", 1).exists()
    v = publish(model)  # the reserved number is burnt; the first visible version is active
    assert (v.version, v.active) == (2, True)


_CRASH = textwrap.dedent(
    """
    import os, sys
    from pathlib import Path
    from service.encoding import ModelParams, build_model
    from service.encoding.synthetic import smooth_route
    from service.registry import Registry

    def die(*args, **kwargs):
        os._exit(3)  # the process dies after the artifact write, before the transaction

    Registry._commit_version = die
    model = build_model(ModelParams.parse(trainer="ridge")).fit(smooth_route(100, 16).reference)
    Registry(Path(sys.argv[1])).publish("crashy", model, params={}, extractor=None, metrics={})
    """
)


def test_process_crash_before_commit_leaves_an_invisible_orphan(tmp_path):
    data = tmp_path / "data"
    proc = subprocess.run([sys.executable, "-c", _CRASH, str(data)], capture_output=True, check=False)
    assert proc.returncode == 3, proc.stderr.decode()
    orphan = data / "artifacts" / "crashy" / "v1"
    assert (orphan / "manifest.json").is_file()  # complete artifact, but no row
    reg = Registry(data)  # the default grace period keeps a fresh orphan (publish in flight?)
    assert orphan.exists()
    with pytest.raises(NotFoundError):
        reg.get_map("crashy")
    assert reg.list_maps() == []
    assert reg.cleanup_orphans(min_age_s=0) == [orphan]
    assert not orphan.exists()


def test_cleanup_keeps_published_versions(registry, publish, model):
    publish(model)
    assert registry.cleanup_orphans(min_age_s=0) == []
    assert registry.load_model("route-a", 1) is not None


def test_commit_refuses_an_artifact_removed_meanwhile(registry, publish, model, monkeypatch):
    original = Registry._commit_version

    def cleaned_before_commit(self: Registry, name: str, version: int, path: Path, *a: object):
        self.cleanup_orphans(min_age_s=0)  # a concurrent cleanup sees an orphan and removes it
        return original(self, name, version, path, *a)  # type: ignore[arg-type]

    monkeypatch.setattr(Registry, "_commit_version", cleaned_before_commit)
    with pytest.raises(ArtifactError, match="disappeared"):
        publish(model)
    monkeypatch.undo()
    with pytest.raises(NotFoundError):
        registry.get_map("route-a")


def test_generation_bumps_on_publish_activate_delete_only(registry, publish, model, other_model):
    g0 = registry.generation()
    publish(model)
    g1 = registry.generation()
    publish(other_model)
    g2 = registry.generation()
    registry.list_maps()
    registry.get_version("route-a", 1)
    registry.load_model("route-a", 1)
    assert registry.generation() == g2
    registry.activate("route-a", 2)
    g3 = registry.generation()
    registry.delete_version("route-a", 1)
    g4 = registry.generation()
    assert g0 < g1 < g2 < g3 < g4


def _publish_and_activate(
    data_dir: str, url: str | None, model: PlaceRecognizer, n: int, out: mp.Queue,
    mode: JournalMode,
) -> None:  # fmt: skip
    reg = Registry(Path(data_dir), url=url, journal_mode=mode)
    mine = []
    for _ in range(n):
        v = reg.publish("shared", model, params={}, extractor=None, metrics={}).version
        mine.append(v)
        reg.activate("shared", v)  # another process may activate its own right after
    out.put(mine)


@pytest.mark.parametrize("store", ["sqlite-wal", "sqlite-delete", "postgresql"])
def test_concurrent_publishers_and_activators_in_several_processes(tmp_path, model, store,
                                                                   request):  # fmt: skip
    url: str | None = None
    mode: JournalMode = "delete" if store == "sqlite-delete" else "wal"
    if store == "postgresql":
        url = request.getfixturevalue("pg_url")
        empty_database(url)
    ctx = mp.get_context("fork")  # no threads in the test process; fork keeps this fast
    out: mp.Queue = ctx.Queue()
    first = Registry(tmp_path, url=url, journal_mode=mode)  # the parent's pool is not shared
    g0 = first.generation()
    procs = [ctx.Process(target=_publish_and_activate,
                         args=(str(tmp_path), url, model, 4, out, mode))
             for _ in range(3)]  # fmt: skip
    for p in procs:
        p.start()
    results = [out.get(timeout=90) for _ in procs]
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    versions = sorted(v for r in results for v in r)
    assert versions == list(range(1, 13))  # distinct, none lost, none reused
    reg = Registry(tmp_path, url=url, journal_mode=mode)
    info = reg.get_map("shared")
    assert info.versions == versions
    assert info.active_version in versions
    assert sum(v.active for v in reg.list_versions("shared")) == 1
    assert reg.generation() == g0 + 24  # every publish and activation counted once
    for v in versions:
        reg.load_model("shared", v)
    first.close()
    reg.close()


def test_rollback_journal_for_network_filesystems(tmp_path, model):
    import sqlite3

    reg = Registry(tmp_path, journal_mode="delete")
    reg.publish("m", model, params={}, extractor=None, metrics={})
    assert reg.load_model("m", 1) is not None
    with sqlite3.connect(tmp_path / "registry.sqlite3") as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
    assert not (tmp_path / "registry.sqlite3-wal").exists()
    again = Registry(tmp_path, journal_mode="wal")  # nobody else connected: it converts
    assert again.get_map("m").versions == [1]
