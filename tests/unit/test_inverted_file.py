"""The inverted file over one prototype per frame, and the int8 products of the serving plan."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from unittest.mock import patch

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import PhaseEncoder, load_model, save_model
from service.encoding import inverted_file
from service.encoding.inverted_file import (DEFAULT_NPROBE, GEMM_RANK_ROWS, MIN_CANDIDATES,
                                            InvertedFile, default_nlist, default_nprobe)
from service.encoding import ivf_scan
from service.encoding.ivf_scan import ListOrder, search
from service.encoding.quantization import QuantizedLinear, int8_products, int8_products64
from service.encoding.serving_plan import DigitBlock, ServingPlan, plan_for
from service.encoding.synthetic import smooth_route
from service.errors import ArtifactError, InvalidParameterError


def robust(**kw: object) -> PhaseEncoder:
    """The ``robust`` preset's shape on a small route: PCA, one int8 prototype per frame."""
    params: dict[str, object] = dict(n_patterns=1, rho=1.0, trainer="prototype", code="residue",
                                     n_components=24, dtype="int8", temperature=0.028)  # fmt: skip
    params.update(kw)
    return PhaseEncoder(**params)  # type: ignore[arg-type]


@dataclass
class Rows:
    weight: np.ndarray
    rowscale: np.ndarray | None
    bias: np.ndarray
    beta: float


def brute(rows: Rows, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every frame scored: the best (lowest on ties) and its log-softmax."""
    W = rows.weight.astype(np.float32)
    S = (Z @ W.T) * (1.0 if rows.rowscale is None else rows.rowscale)
    S = (S + rows.bias) * rows.beta
    best = S.max(axis=1, keepdims=True)
    return S.argmax(axis=1), -np.log(np.exp(S - best).sum(axis=1))


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 300), m=st.integers(1, 12), nlist=st.integers(1, 40),
       seed=st.integers(0, 2**16), n_queries=st.integers(1, 30), ints=st.booleans(),
       block_rows=st.sampled_from([1, 7, 512]),
       list_scores=st.sampled_from([1, 50, 1 << 18]))  # fmt: skip
def test_probing_every_list_is_the_flat_scan(n: int, m: int, nlist: int, seed: int,
                                             n_queries: int, ints: bool, block_rows: int,
                                             list_scores: int) -> None:  # fmt: skip
    """Whatever the blocks of rows and of (frame, query) scores the scans work in."""
    with (patch.object(ivf_scan, "BLOCK_ROWS", block_rows),
          patch.object(ivf_scan, "LIST_SCORES", list_scores)):  # fmt: skip
        _every_list_is_the_flat_scan(n, m, nlist, seed, n_queries, ints)


def _every_list_is_the_flat_scan(n: int, m: int, nlist: int, seed: int, n_queries: int,
                                 ints: bool) -> None:  # fmt: skip
    rng = np.random.default_rng(seed)
    if ints:  # small integers: many exact ties, which must go to the lowest frame
        rows = Rows(rng.integers(-3, 4, (n, m)).astype(np.int8), np.ones(n, np.float32),
                    np.zeros(n), 1.0)  # fmt: skip
        Z = rng.integers(-2, 3, (n_queries, m)).astype(np.float32)
    else:
        rows = Rows(rng.integers(-127, 128, (n, m)).astype(np.int8),
                    rng.uniform(0.001, 0.01, n).astype(np.float32), rng.normal(0, 0.1, n), 20.0)
        Z = rng.standard_normal((n_queries, m)).astype(np.float32)
    k = min(n, nlist)
    ivf = InvertedFile.fit(rows.weight, rows.rowscale, k, nprobe=k, seed=seed)
    assert sorted(ivf.members.tolist()) == list(range(n))
    want_index, want_score = brute(rows, Z)
    index, score = search(ivf, rows, Z)
    np.testing.assert_array_equal(index, want_index)
    np.testing.assert_allclose(score, want_score, rtol=1e-5, atol=1e-5)
    by_list = search(ivf, rows, Z, order=ListOrder.of(ivf, rows))  # the same arithmetic
    np.testing.assert_array_equal(by_list[0], index)
    np.testing.assert_array_equal(by_list[1], score)
    for i in range(n_queries):  # the one-query path answers as the batch path
        one, one_score = search(ivf, rows, Z[i : i + 1])
        assert one[0] == index[i]
        np.testing.assert_allclose(one_score[0], score[i], rtol=1e-5, atol=1e-5)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(20, 400), nprobe=st.integers(1, 6), seed=st.integers(0, 2**16))
def test_a_partial_probe_answers_the_best_of_its_lists(n: int, nprobe: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    rows = Rows(rng.integers(-127, 128, (n, 8)).astype(np.int8),
                rng.uniform(0.001, 0.01, n).astype(np.float32), np.zeros(n), 1.0)  # fmt: skip
    ivf = InvertedFile.fit(rows.weight, rows.rowscale, 10, nprobe=nprobe, seed=seed)
    Z = rng.standard_normal((5, 8)).astype(np.float32)
    index, score = search(ivf, rows, Z)
    single = [search(ivf, rows, Z[i : i + 1]) for i in range(5)]
    by_list = search(ivf, rows, Z, order=ListOrder.of(ivf, rows))
    np.testing.assert_array_equal(by_list[0], index)
    np.testing.assert_array_equal(by_list[1], score)
    assert ivf.most_scored(ivf.nlist) == ivf.nlist + n  # every list: every frame, centroids too
    for i, lists in enumerate(ivf.lists(Z)):
        cand = np.sort(ivf.candidates(lists))
        assert ivf.nlist + cand.size <= ivf.most_scored()  # what the work budget counts
        sub = Rows(rows.weight[cand], rows.rowscale[cand], rows.bias[cand], 1.0)  # type: ignore[index]
        j, s = brute(sub, Z[i : i + 1])
        assert index[i] == cand[j[0]] == single[i][0][0]
        np.testing.assert_allclose([score[i], single[i][1][0]], s[0], rtol=1e-5, atol=1e-5)
        S = ((Z[i] @ rows.weight.astype(np.float32).T) * rows.rowscale).astype(np.float64)
        flat_lp = S[index[i]] - S.max() - np.log(np.exp(S - S.max()).sum())
        assert score[i] >= flat_lp - 1e-5  # an upper bound of the frame's flat log-softmax


def test_list_order_copies_of_another_partition_are_not_used() -> None:
    rng = np.random.default_rng(5)
    n = 300
    rows = Rows(rng.integers(-127, 128, (n, 8)).astype(np.int8),
                rng.uniform(0.001, 0.01, n).astype(np.float32), rng.normal(0, 0.1, n), 20.0)
    ivf = InvertedFile.fit(rows.weight, rows.rowscale, 12, nprobe=3, seed=0)
    other = InvertedFile.fit(rows.weight, rows.rowscale, 7, nprobe=3, seed=1)
    Z = rng.standard_normal((20, 8)).astype(np.float32)
    want = search(ivf, rows, Z)
    stale = ListOrder.of(other, rows)  # scales and biases in another file's order
    got = search(ivf, rows, Z, order=stale)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert ListOrder.of(ivf, rows).nbytes == n * (4 + 8)


def test_the_plan_keeps_list_order_copies_only_for_a_partial_probe() -> None:
    route = smooth_route(600, 32, seed=2)
    partial = plan_for(robust(search="ivf", nprobe=3).fit(route.reference))
    assert partial._by_list is not None and partial.ivf is not None
    assert partial._by_list.members is partial.ivf.members
    every = plan_for(robust(search="ivf", nlist=5, nprobe=5).fit(route.reference))
    assert every._by_list is None  # served by the flat scan


@settings(max_examples=30, deadline=None)
@given(nlist=st.integers(1, 60), nprobe=st.integers(1, 60), n_queries=st.integers(1, 40),
       seed=st.integers(0, 2**16), block=st.sampled_from([1, 9, 97, 256]))  # fmt: skip
def test_a_batch_ranks_the_lists_as_each_query_alone(nlist: int, nprobe: int, n_queries: int,
                                                     seed: int, block: int) -> None:  # fmt: skip
    """Batches from GEMM_RANK_ROWS queries rank the centroids by one product per block of rows;
    the lists, their order included, are those FAISS gives each query alone."""
    rng = np.random.default_rng(seed)
    C = rng.standard_normal((nlist, 16)).astype(np.float32)
    C /= np.linalg.norm(C, axis=1, keepdims=True)
    ivf = InvertedFile(C, np.arange(nlist, dtype=np.int32), np.arange(nlist + 1), 1)
    Z = rng.standard_normal((n_queries, 16)).astype(np.float32)
    p = min(nlist, nprobe)
    with patch.object(inverted_file, "_RANK_BLOCK_ROWS", block):
        got = ivf.lists(Z, nprobe)
    alone = np.concatenate([ivf.lists(Z[i : i + 1], nprobe) for i in range(n_queries)])
    assert got.shape == (n_queries, p) and got.dtype == np.int64
    S = Z.astype(np.float64) @ C.T.astype(np.float64)
    for i in range(n_queries):
        gaps = np.diff(np.sort(S[i])[::-1])
        if gaps.size and np.abs(gaps).min() < 1e-4:  # near-ties: float32 products may differ
            continue
        assert got[i].tolist() == alone[i].tolist()


def test_centroids_that_score_alike_rank_the_lower_list_first_in_a_batch() -> None:
    C = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [0.0, 1.0]], dtype=np.float32)
    ivf = InvertedFile(C, np.arange(4, dtype=np.int32), np.arange(5), 1)
    Z = np.tile(np.array([[1.0, 0.5]], dtype=np.float32), (GEMM_RANK_ROWS, 1))
    assert ivf.lists(Z, 4).tolist() == [[0, 2, 1, 3]] * GEMM_RANK_ROWS
    three = ivf.lists(Z, 3).tolist()  # 1 and 3 tie for the last place: either, once
    assert three[0][:2] == [0, 2] and three[0][2] in (1, 3) and three == [three[0]] * GEMM_RANK_ROWS


def test_the_default_lists_and_probes() -> None:
    assert default_nlist(1_000_000) == 4000 and default_nprobe(4000, 1_000_000) == 20
    assert default_nlist(100_000) == 1265 and default_nprobe(1265, 100_000) == 52
    assert default_nlist(3_576) == 239 and default_nprobe(239, 3_576) == 239  # Nordland: whole
    assert default_nlist(3) == 3 and default_nprobe(3, 3) == 3


@given(st.integers(1, 5_000_000), st.floats(0.05, 1.0))
def test_the_default_probes_hold_the_candidate_floor(n: int, f: float) -> None:
    """At least 20 lists, and lists holding MIN_CANDIDATES prototypes on average, or all."""
    nlist = max(1, min(n, round(f * default_nlist(n))))
    p = default_nprobe(nlist, n)
    assert 1 <= p <= nlist
    assert p == nlist or (p >= DEFAULT_NPROBE and p * n / nlist >= MIN_CANDIDATES)
    assert p == nlist or p == DEFAULT_NPROBE or (p - 1) * n / nlist < MIN_CANDIDATES  # the least


@pytest.mark.parametrize("n_queries", [1, 40])
def test_ivf_probing_everything_answers_as_the_flat_scan(n_queries: int) -> None:
    route = smooth_route(900, 48, seed=3)
    model = robust(search="ivf", nlist=30, nprobe=30).fit(route.reference)
    assert model.ivf_ is not None and model.ivf_.nlist == 30
    Q = route.query[:n_queries].astype(np.float64)
    plan = plan_for(model)
    dg = plan.phases[0].digits[0]
    Zc = np.ascontiguousarray(plan.normalise(Q, np.float32).take(dg.columns, axis=1))
    index, log_score = search(model.ivf_, dg, Zc, 30)  # the index itself, every list
    flat = model.localize(Q, search="flat")
    np.testing.assert_array_equal(index, flat.index)
    np.testing.assert_allclose(log_score, flat.log_score, rtol=1e-5, atol=1e-6)


def test_an_index_probing_every_list_is_served_by_the_flat_scan() -> None:
    route = smooth_route(900, 48, seed=3)
    model = robust(search="ivf", nlist=30, nprobe=30).fit(route.reference)
    Q = route.query[:40].astype(np.float64)
    with patch("service.encoding.serving_plan.ivf_search", side_effect=AssertionError):
        served = model.localize(Q)
    np.testing.assert_array_equal(served.index, model.localize(Q, search="flat").index)
    partial = robust(search="ivf", nlist=30, nprobe=29).fit(route.reference)
    with patch("service.encoding.serving_plan.ivf_search", side_effect=AssertionError):
        with pytest.raises(AssertionError):
            partial.localize(Q)


def test_ivf_with_few_probes_keeps_the_flat_scans_precision() -> None:
    route = smooth_route(3000, 48, seed=4, query_noise=0.8)
    model = robust(search="ivf", nprobe=20).fit(route.reference)  # below the default's floor
    assert model.ivf_ is not None and model.ivf_.nprobe == 20 < model.ivf_.nlist
    truth = np.arange(3000)
    flat = np.abs(model.localize(route.query, search="flat").index - truth) <= 5
    ivf = np.abs(model.localize(route.query).index - truth) <= 5
    assert ivf.mean() >= flat.mean() - 0.01


def test_the_default_scans_a_short_routes_lists_whole() -> None:
    """Fewer than MIN_CANDIDATES prototypes in all: every list, the flat scan's answers."""
    route = smooth_route(1500, 32, seed=6, query_noise=0.8)
    model = robust(search="ivf").fit(route.reference)
    assert model.ivf_ is not None and model.ivf_.nprobe == model.ivf_.nlist == default_nlist(1500)
    Q = route.query[:300].astype(np.float64)
    np.testing.assert_array_equal(model.localize(Q).index, model.localize(Q, search="flat").index)


def test_auto_and_flat_build_no_inverted_file_on_a_short_route() -> None:
    route = smooth_route(200, 16, seed=1)
    assert robust().fit(route.reference).ivf_ is None
    assert robust(search="flat").fit(route.reference).ivf_ is None
    multi = robust(n_patterns=2, search="ivf").fit(route.reference)  # k = 2: not a frame each
    assert multi.ivf_ is None


@pytest.mark.parametrize("bad", [{"search": "tree"}, {"nlist": 0}, {"nprobe": 0}])
def test_bad_search_parameters_are_refused(bad: dict[str, object]) -> None:
    with pytest.raises(InvalidParameterError):
        robust(**bad).fit(smooth_route(50, 8).reference)


def test_the_inverted_file_is_saved_and_checked_on_load(tmp_path: Path) -> None:
    route = smooth_route(500, 24, seed=2)
    model = robust(search="ivf", nlist=12, nprobe=3).fit(route.reference)
    save_model(model, tmp_path / "m")
    back = load_model(tmp_path / "m")
    assert back.ivf_ is not None and back.ivf_.nprobe == 3  # type: ignore[attr-defined]
    np.testing.assert_array_equal(back.ivf_.members, model.ivf_.members)  # type: ignore[attr-defined]
    Q = route.query.astype(np.float64)
    np.testing.assert_array_equal(back.localize(Q).index, model.localize(Q).index)
    assert model.footprint().components["inverted file"].actual_bytes == model.ivf_.nbytes + 8
    arrays, meta = model._to_arrays()
    arrays["ivf.members"] = np.zeros_like(arrays["ivf.members"])  # every frame in list 0's slot
    with pytest.raises(ValueError, match="misses frames"):
        PhaseEncoder._from_arrays(model.get_params(), arrays, meta)
    del arrays["ivf.centroids"]  # no inverted file stored: the flat scan
    assert PhaseEncoder._from_arrays(model.get_params(), arrays, meta).ivf_ is None


def test_a_corrupt_inverted_file_is_an_artifact_error(tmp_path: Path) -> None:
    from safetensors.numpy import load_file, save_file

    from service.encoding.artifacts import TENSORS, sha256_file

    model = robust(search="ivf", nlist=5).fit(smooth_route(100, 16).reference)
    save_model(model, tmp_path / "m")
    tensors = tmp_path / "m" / TENSORS
    arrays = load_file(str(tensors))
    arrays["ivf.offsets"] = arrays["ivf.offsets"][:-1].copy()
    save_file(arrays, str(tensors))
    manifest = tmp_path / "m" / "manifest.json"
    import json

    man = json.loads(manifest.read_text())
    man["files"][TENSORS]["sha256"] = sha256_file(tensors)
    manifest.write_text(json.dumps(man))
    with pytest.raises(ArtifactError, match="inverted file"):
        load_model(tmp_path / "m")


def test_int8_products_are_those_of_the_float32_copy() -> None:
    rng = np.random.default_rng(0)
    W = rng.standard_normal((20_000, 16))
    lin = QuantizedLinear.from_dense(W, np.zeros(20_000), "int8")
    Z = rng.standard_normal((3, 16)).astype(np.float32)
    copy = (lin.weight.astype(np.float64) * lin.scale[:, None]).astype(np.float32)  # type: ignore[index]
    np.testing.assert_allclose(int8_products(Z, lin.weight, lin.scale), Z @ copy.T,  # type: ignore[arg-type]
                               rtol=1e-5, atol=1e-5)  # fmt: skip


@settings(max_examples=30, deadline=None)
@given(tau=st.integers(1, 5000), m=st.integers(1, 24), n=st.integers(1, 4),
       seed=st.integers(0, 2**16))  # fmt: skip
def test_int8_float64_products_are_the_dequantised_models(tau: int, m: int, n: int,
                                                          seed: int) -> None:  # fmt: skip
    rng = np.random.default_rng(seed)
    lin = QuantizedLinear.from_dense(rng.standard_normal((tau, m)), np.zeros(tau), "int8")
    Z = rng.standard_normal((n, m))
    W, _ = lin.dequantized()
    np.testing.assert_allclose(int8_products64(Z, lin.weight, lin.scale), Z @ W.T,  # type: ignore[arg-type]
                               rtol=1e-13, atol=1e-13)  # fmt: skip


def test_long_int8_weights_score_every_frame_without_a_float64_copy(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    route = smooth_route(3000, 32, seed=7)  # several blocks of float64 rows
    model = robust(search="flat").fit(route.reference)
    Q = route.query[:6].astype(np.float64)
    copied = plan_for(model)
    want, want64 = copied.frame_log_scores(Q), copied.decode(Q, "float64")
    monkeypatch.setattr("service.encoding.serving_blocks.FLOAT32_COPY_BYTES", 0)
    monkeypatch.setattr("service.encoding.float64_cache.CACHE_BYTES", 0)
    plan = ServingPlan(model)
    digit = plan.phases[0].digits[0]
    assert digit.long64

    def refused(_self: DigitBlock) -> None:
        raise AssertionError("a float64 copy of the weights was made")

    monkeypatch.setattr(DigitBlock, "_make_dense64", refused)
    np.testing.assert_allclose(plan.frame_log_scores(Q), want, rtol=1e-12, atol=1e-12)
    got64 = plan.decode(Q, "float64")
    np.testing.assert_array_equal(got64.index, want64.index)
    np.testing.assert_allclose(got64.log_score, want64.log_score, rtol=1e-12, atol=1e-12)


def test_large_int8_weights_are_served_without_a_float32_copy(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    route = smooth_route(700, 32, seed=6)
    model = robust(search="flat").fit(route.reference)
    Q = route.query.astype(np.float64)
    copied = plan_for(model)
    monkeypatch.setattr("service.encoding.serving_blocks.FLOAT32_COPY_BYTES", 0)
    plan = ServingPlan(model)
    digit = plan.phases[0].digits[0]
    assert digit.weight is model.digits_[0].linear.weight and digit.rowscale is not None
    for rows in (Q[:1], Q[1:2], Q):  # the one-query path and the batch path: certified answers
        a, b = plan.decode(rows), copied.decode(rows)
        np.testing.assert_array_equal(a.index, b.index)
        np.testing.assert_allclose(a.log_score, b.log_score, rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(plan.decode(Q, "float64").index, a.index)


@pytest.mark.parametrize("dtype", ["int8", "float32"])
def test_one_prototype_per_frame_streamed_is_the_regular_fit(
    dtype: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("service.encoding.prototype._STREAM_ROWS", 97)  # several blocks
    route = smooth_route(1000, 40, seed=8)
    X32 = route.reference.astype(np.float32)
    steps: list[tuple[int, int]] = []
    streamed = robust(dtype=dtype).fit(X32, progress=lambda _d, done, total: steps.append((done, total)))
    assert steps[-1][0] == steps[-1][1] == 1000 and len(steps) > 5
    monkeypatch.setattr(PhaseEncoder, "_one_prototype_per_row", lambda *a: False)
    regular = robust(dtype=dtype).fit(route.reference.astype(np.float64))
    a, b = streamed.digits_[0], regular.digits_[0]
    np.testing.assert_array_equal(a.columns, b.columns)
    np.testing.assert_array_equal(a.linear.weight, b.linear.weight)
    np.testing.assert_array_equal(a.linear.bias, b.linear.bias)
    if dtype == "int8":
        np.testing.assert_array_equal(a.linear.scale, b.linear.scale)  # type: ignore[arg-type]
    np.testing.assert_allclose(a.pattern.scores, b.pattern.scores, rtol=1e-6)  # type: ignore[union-attr]
    assert a.temperature == b.temperature and streamed.n_frames_ == regular.n_frames_ == 1000
    assert streamed.n_features_in_ == 40
    Q = route.query.astype(np.float64)
    np.testing.assert_array_equal(streamed.localize(Q).index, regular.localize(Q).index)


def test_training_parameters_name_the_search() -> None:
    from service.encoding import ModelParams, build_model

    assert build_model(ModelParams.parse()).search == "auto"  # type: ignore[union-attr]
    assert build_model(ModelParams.parse(search="ivf")).search == "ivf"  # type: ignore[union-attr]
    with pytest.raises(InvalidParameterError, match="search"):
        ModelParams.parse(search="tree")
