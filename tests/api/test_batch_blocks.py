"""A large batch is scored a block of rows at a time (bounded memory) with exactly the answers
of one ``model.localize`` over the whole batch. Data is SYNTHETIC (conftest's route)."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from service.core import localization


def test_blockwise_answers_equal_one_call(client: TestClient, trained: str, route, monkeypatch) -> None:
    monkeypatch.setattr(localization, "SCORE_BLOCK_BYTES", 1)  # blocks of MIN_BLOCK_ROWS = 64
    Q = np.concatenate([route[1]] * 2)  # 240 queries: 4 blocks, the last one partial
    model = client.app.state.context.store.get(trained).model  # type: ignore[attr-defined]
    want = model.localize(Q)
    r = client.post(f"/v1/localize/batch?map={trained}&d={Q.shape[1]}",
                    content=Q.astype("<f4").tobytes(),
                    headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["n"] == len(Q) and body["index"] == want.index.tolist()
    assert body["chunk"] == want.chunk.tolist()
    # the same frames; confidences to float32 rounding (the fast path's products are float32,
    # and BLAS sums a 64-row block and a 240-row call in different orders)
    np.testing.assert_allclose(body["confidence"], want.confidence, rtol=1e-6)
