"""``gridplace bench quality`` on a tiny SYNTHETIC folder: every protocol, method and drive is
reported, the splits never mix test rows into training, and the CLI flags work."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from service.bench.quality_bench import (
    KINDS,
    descriptor_pair,
    drive_adapter,
    load_sets,
    measure,
    merge_reports,
    run_quality_bench,
)
from service.bench.quality_protocols import cross_folds, folds_for, query_halves
from service.bench.quality_report import markdown_tables, plot_frontier
from service.cli import app
from service.encoding import ExactNN
from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter, route_statistics
from service.encoding.base import precision_at
from service.encoding.normalization import Normalizer
from service.encoding.sequence import SequenceConfig
from service.encoding.synthetic import smooth_route
from service.errors import InvalidInputError, InvalidParameterError
from service.harness.projected_nn import ProjectedNN
from service.harness.quality_methods import PlacePooled, QualityMethod, catalogue, fit_places

N, D = 300, 16
METHODS = "exact_nn,pq-m16,yu,nn-pca64,ridge,robust"


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("route")
    route = smooth_route(N, D, seed=1)
    np.save(root / "reference.npy", route.reference)
    np.save(root / "query.npy", route.query)
    return root


@pytest.fixture(scope="module")
def report(folder: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("out") / "q.json"
    sets = load_sets(folder, [])
    return run_quality_bench(sets, ("cross", "multi"), METHODS, SequenceConfig(), out, argv=["t"])


def test_halves_partition_the_drive() -> None:
    h = query_halves(7)
    assert h["A"].tolist() == [0, 1, 2] and h["B"].tolist() == [3, 4, 5, 6]
    assert h["all"].tolist() == list(range(7))
    with pytest.raises(InvalidParameterError):
        query_halves(1)


def test_multi_folds_never_train_on_their_test_rows() -> None:
    ref = np.zeros((10, 2), dtype=np.float32)
    qry = np.arange(20, dtype=np.float32).reshape(10, 2) + 100
    folds = folds_for("multi", ref, qry, np.arange(10))
    assert len(folds) == 2
    for fold in folds:
        ((half, rows),) = fold.drives.items()
        trained = {tuple(r) for r in fold.train_rows.tolist()}
        assert not trained & {tuple(r) for r in qry[rows].tolist()}, half
        assert fold.train_places is not None and fold.train_places.shape[0] == 15
        assert np.array_equal(fold.train_places[:10], np.arange(10))


def test_every_method_protocol_and_drive_is_reported(report: dict[str, Any]) -> None:
    (entry,) = report["sets"]
    assert entry["dataset"]["N"] == N and entry["dataset"]["d"] == D
    cross, multi = entry["protocols"]["cross"], entry["protocols"]["multi"]
    assert [r["method"] for r in cross["results"]] == ["exact-nn", "pq-m16", "yu", "nn-pca64",
                                                       "ridge", "robust"]  # fmt: skip
    for r in cross["results"]:
        assert set(r["drives"]) == {"A", "B", "all"}
        for d in r["drives"].values():
            for kind in ("single", "sequence"):
                assert list(d[kind]) == ["0", "2", "5", "10"]
                assert all(0.0 <= p <= 1.0 for p in d[kind].values())
                assert d[kind]["0"] <= d[kind]["10"]
        assert r["actual_bytes"] > 0 and r["paper_bytes"] > 0
    nn = cross["results"][0]
    assert nn["bytes_vs_exact_nn"] == 1.0 and nn["drives"]["all"]["single"]["5"] > 0.9
    # the whole drive is the query-weighted mean of its halves for single frames
    a, b, whole = (nn["drives"][k]["single"]["5"] for k in ("A", "B", "all"))
    assert whole == pytest.approx((a * 150 + b * 150) / 300)
    # multi-traversal: baselines pooled per place, gridplace fitted with places=
    pooled = {r["method"]: r for r in multi["results"]}
    assert {"exact-nn", "pq-m16", "yu", "nn-pca64"} <= set(pooled)
    assert pooled["exact-nn"]["folds"] == ["train reference+A, test B", "train reference+B, test A"]
    assert pooled["exact-nn"]["drives"]["all"]["n"] == N
    assert pooled["exact-nn"]["actual_bytes"] > nn["actual_bytes"]  # it stores both traversals
    assert {r["method"] for r in multi["results"]} == {
        "exact-nn", "pq-m16", "yu", "nn-pca64", "ridge", "robust"}  # fmt: skip


def test_the_frontier_figure_is_a_png(report: dict[str, Any], tmp_path: Path) -> None:
    path = plot_frontier(report, tmp_path / "f.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_place_pooling_of_identical_traversals_equals_one_traversal() -> None:
    route = smooth_route(80, 8, seed=2)
    X = route.reference
    one = ExactNN().fit(X)
    two = fit_places(ExactNN(), np.concatenate([X, X]), np.r_[np.arange(80), np.arange(80)])
    assert isinstance(two, PlacePooled)
    assert np.array_equal(two.localize(route.query).index, one.localize(route.query).index)
    assert two.frame_log_scores(route.query).shape == (80, 80)
    with pytest.raises(InvalidParameterError, match="every place"):
        PlacePooled(ExactNN()).fit(X[:3], np.array([0, 2, 2]))


def test_unknown_methods_and_bad_pairs_are_named(folder: Path, tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="nope"):
        catalogue(D, N, "exact_nn,nope")
    np.save(tmp_path / "r.npy", np.zeros((5, 3), dtype=np.float32))
    np.save(tmp_path / "q.npy", np.zeros((5, 4), dtype=np.float32))
    with pytest.raises(InvalidInputError, match="same d"):
        descriptor_pair(tmp_path / "r.npy", tmp_path / "q.npy")
    np.save(tmp_path / "q.npy", np.zeros((0, 3), dtype=np.float32))
    with pytest.raises(InvalidInputError, match="n ≥ 1"):
        descriptor_pair(tmp_path / "r.npy", tmp_path / "q.npy")


def test_a_pair_given_by_relative_paths_is_named_after_its_folder(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    (tmp_path / "route7").mkdir()
    np.save(tmp_path / "route7" / "r.npy", np.ones((4, 3), dtype=np.float32))
    np.save(tmp_path / "route7" / "q.npy", np.ones((4, 3), dtype=np.float32))
    monkeypatch.chdir(tmp_path / "route7")
    ds = descriptor_pair(Path("r.npy"), Path("q.npy"))
    assert ds.name == "route7" and ds.label.startswith("route7: reference 4 x query 4")


def test_cli_on_a_descriptor_pair_writes_json_and_a_figure(folder: Path, tmp_path: Path) -> None:
    out, fig = tmp_path / "q.json", tmp_path / "q.png"
    res = CliRunner().invoke(app, [
        "bench", "quality", "--reference", str(folder / "reference.npy"),
        "--query", str(folder / "query.npy"), "--protocols", "cross", "--methods", "exact_nn,ridge",
        "--filter", "emission_scale=0.2", "--out", str(out), "--figure", str(fig),
    ], env={"COLUMNS": "200"})  # fmt: skip
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert data["sequence_filter"]["emission_scale"] == 0.2
    assert [r["method"] for r in data["sets"][0]["protocols"]["cross"]["results"]] == [
        "exact-nn", "ridge"]  # fmt: skip
    assert "exact-nn" in res.output and fig.is_file()


def test_cli_rejects_unpaired_and_unknown_options(folder: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    res = runner.invoke(app, ["bench", "quality", "--reference", str(folder / "reference.npy"),
                              "--out", str(tmp_path / "x.json")])  # fmt: skip
    assert res.exit_code == 2 and "--query" in res.output
    res = runner.invoke(app, ["bench", "quality", str(folder), "--protocols", "sideways",
                              "--out", str(tmp_path / "x.json")])  # fmt: skip
    assert res.exit_code == 2 and "sideways" in res.output


def test_merged_runs_put_every_method_side_by_side(folder: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    outs = []
    for i, methods in enumerate(("exact_nn,ridge", "ridge,yu")):
        outs.append(tmp_path / f"run{i}.json")
        res = runner.invoke(app, ["bench", "quality", str(folder), "--protocols", "cross",
                                  "--methods", methods, "--out", str(outs[-1])])  # fmt: skip
        assert res.exit_code == 0, res.output
    merged = tmp_path / "merged.json"
    md = tmp_path / "tables.md"
    res = runner.invoke(app, ["bench", "quality", "--merge", str(outs[0]), "--merge", str(outs[1]),
                              "--out", str(merged), "--markdown", str(md)])  # fmt: skip
    assert res.exit_code == 0, res.output
    table = md.read_text()
    assert "| `exact-nn` |" in table and "| `yu` |" in table and "sequence B" in table
    data = json.loads(merged.read_text())
    (entry,) = data["sets"]
    rows = entry["protocols"]["cross"]["results"]
    assert [r["method"] for r in rows] == ["exact-nn", "yu", "ridge"] and len(data["runs"]) == 2
    assert rows[1]["bytes_vs_exact_nn"] == rows[1]["actual_bytes"] / rows[0]["actual_bytes"]
    res = runner.invoke(app, ["bench", "quality", "--merge", str(outs[0]), "--merge", str(outs[1]),
                              "--methods", "exact_nn,yu", "--out", str(merged)])  # fmt: skip
    assert res.exit_code == 0, res.output
    rows = json.loads(merged.read_text())["sets"][0]["protocols"]["cross"]["results"]
    assert [r["method"] for r in rows] == ["exact-nn", "yu"]


# -- appearance adaptation ------------------------------------------------------------------
ADAPTED = ("single_adapted", "sequence_adapted")


def test_every_drive_is_also_measured_adapted_and_pooled(report: dict[str, Any]) -> None:
    assert report["adaptation"]["config"] == AdaptationConfig().model_dump()
    (entry,) = report["sets"]
    for block in entry["protocols"].values():
        for r in block["results"]:
            assert r["adaptation"]["config"] == AdaptationConfig().model_dump()
            assert r["adapt_us_per_frame"] > 0
            for d in r["drives"].values():
                for kind in ADAPTED:
                    assert list(d[kind]) == ["0", "2", "5", "10"]
                    assert all(0.0 <= p <= 1.0 for p in d[kind].values())
    used = {(key, r["method"]): r["adaptation"]["statistics"]
            for key, block in entry["protocols"].items() for r in block["results"]}  # fmt: skip
    assert used["cross", "robust"] == used["cross", "exact-nn"] == "model"
    assert used["cross", "nn-pca64"] == "training rows"  # ProjectedNN keeps no normaliser
    assert used["multi", "exact-nn"] == "training rows"  # pooled per place: the wrapper has none
    assert used["multi", "robust"] == "model"
    # (b) pools each fold's unseen half, adapted figures like the others
    robust = next(r for r in entry["protocols"]["multi"]["results"] if r["method"] == "robust")
    a, b, pooled = (robust["drives"][k] for k in ("A", "B", "all"))
    for kind in KINDS:
        for t in ("0", "5"):
            want = (a[kind][t] * a["n"] + b[kind][t] * b["n"]) / (a["n"] + b["n"])
            assert pooled[kind][t] == pytest.approx(want)


def _shifted_route(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A route whose query drive is every column rescaled and shifted (another season)."""
    route = smooth_route(200, 12, seed=seed)
    rng = np.random.default_rng(0)
    query = route.query * rng.uniform(0.3, 3.0, 12) + rng.normal(0.0, 3.0, 12)
    return route.reference, query.astype(np.float32)


def test_a_model_without_statistics_is_adapted_from_its_training_rows() -> None:
    reference, query = _shifted_route()
    truth = np.arange(query.shape[0])
    (fold,) = cross_folds(reference, query.shape[0])
    method = QualityMethod("nn-pca8", "exact_nn_projected", lambda: ProjectedNN(8))
    row = measure(method, fold, query, truth, SequenceConfig())
    assert row["adaptation"]["statistics"] == "training rows"
    model = ProjectedNN(8).fit(reference)
    assert route_statistics(model) is None
    adapter, used = drive_adapter(model, fold, AdaptationConfig())
    stats = Normalizer.fit(reference)
    assert used == "training rows" and np.allclose(adapter.route_mean, stats.mean)
    assert np.allclose(adapter.route_scale, stats.scale)
    for name, drive in fold.drives.items():  # each drive from a fresh adapter, in order
        rows = AppearanceAdapter.for_reference(reference).transform(query[drive])
        pred = model.localize(rows).index
        assert row["drives"][name]["single_adapted"]["2"] == precision_at(pred, truth[drive], 2)
    # the shift is what adaptation removes: it recovers much of the drive (on this smooth
    # route the new-scene rule learns from fewer frames than there are: 0.37 → 0.65)
    whole = row["drives"]["all"]
    assert whole["single_adapted"]["2"] > whole["single"]["2"] + 0.2


def test_a_model_with_statistics_is_adapted_from_its_own() -> None:
    reference, query = _shifted_route()
    (fold,) = cross_folds(reference, query.shape[0])
    (method,) = catalogue(12, 200, "robust")
    model = method.build().fit(reference)
    adapter, used = drive_adapter(model, fold, AdaptationConfig(alpha=0.1))
    assert used == "model" and adapter.config.alpha == 0.1
    assert np.array_equal(adapter.route_mean, route_statistics(model).mean.astype(np.float64))


def _before_adaptation(report: dict[str, Any]) -> dict[str, Any]:
    """``report`` as the bench wrote it before drives were measured adapted."""
    old = copy.deepcopy(report)
    old.pop("adaptation")
    for entry in old["sets"]:
        for block in entry["protocols"].values():
            for r in block["results"]:
                del r["adaptation"], r["adapt_us_per_frame"]
                for d in r["drives"].values():
                    for kind in ADAPTED:
                        del d[kind]
    return old


def test_old_reports_without_adapted_figures_still_merge(report: dict[str, Any],
                                                         tmp_path: Path) -> None:  # fmt: skip
    old = _before_adaptation(report)
    alone = merge_reports([old])
    assert "adaptation" not in alone and "No adapted figures" in markdown_tables(alone)
    fresh = copy.deepcopy(report)
    for block in fresh["sets"][0]["protocols"].values():
        block["results"] = [r for r in block["results"] if r["method"] == "exact-nn"]
    merged = merge_reports([old, fresh])
    assert merged["adaptation"] == report["adaptation"]
    rows = {r["method"]: r for r in merged["sets"][0]["protocols"]["cross"]["results"]}
    assert "single_adapted" in rows["exact-nn"]["drives"]["B"]
    assert "single_adapted" not in rows["robust"]["drives"]["B"]
    table = markdown_tables(merged)
    robust_line = next(line for line in table.splitlines() if line.startswith("| `robust` |"))
    nn_line = next(line for line in table.splitlines() if line.startswith("| `exact-nn` |"))
    assert robust_line.count("—") == 6 and "—" not in nn_line  # (a): 3 drives × 2 kinds
    assert plot_frontier(merged, tmp_path / "m.png").is_file()
