"""The server-wide budget of public requests in flight (counters only; the real-server test is
``tests/integration/test_public_inflight.py``)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.core.public_budget import PublicBudget, PublicLease
from service.errors import CapacityError


def test_requests_beyond_the_count_are_refused_naming_the_setting() -> None:
    budget = PublicBudget(max_requests=2, max_bytes=100)
    a, b = budget.open(10), budget.open(0)
    with pytest.raises(CapacityError, match="GRIDPLACE_MAX_PUBLIC_REQUESTS=2") as refused:
        budget.open(0)
    assert refused.value.http_status == 503 and refused.value.code == "capacity_exhausted"
    a.close()
    a.close()  # idempotent
    budget.open(0).close()
    b.close()
    assert budget.use().requests == 0 and budget.use().nbytes == 0


def test_bodies_beyond_the_bytes_are_refused_declared_or_as_they_arrive() -> None:
    budget = PublicBudget(max_requests=10, max_bytes=100)
    declared = budget.open(60)
    with pytest.raises(CapacityError, match="GRIDPLACE_MAX_PUBLIC_BODIES_MB"):
        budget.open(41)
    chunked = budget.open(0)
    chunked.receive(30)
    with pytest.raises(CapacityError, match="GRIDPLACE_MAX_PUBLIC_BODIES_MB"):
        chunked.receive(11)
    assert budget.use().nbytes == 90  # the refused chunk took nothing
    declared.receive(60)  # within what it reserved
    assert budget.use().nbytes == 90
    chunked.close()
    declared.close()
    assert budget.use() == budget.use().__class__(0, 0)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["open", "receive", "close"]),
                          st.integers(0, 8), st.integers(0, 120)), max_size=60))  # fmt: skip
def test_what_is_held_never_exceeds_the_limits_and_is_all_given_back(
    steps: list[tuple[str, int, int]],
) -> None:
    budget = PublicBudget(max_requests=5, max_bytes=200)
    leases: list[PublicLease] = []
    for op, which, n in steps:
        try:
            if op == "open":
                leases.append(budget.open(n))
            elif leases and op == "receive":
                leases[which % len(leases)].receive(n)
            elif leases:
                leases.pop(which % len(leases)).close()
        except CapacityError:
            pass
        use = budget.use()
        assert 0 <= use.requests <= 5 and 0 <= use.nbytes <= 200
        assert use.requests == sum(not lease.closed for lease in leases)
        assert use.nbytes == sum(lease.reserved for lease in leases if not lease.closed)
    for lease in leases:
        lease.close()
    assert budget.use().requests == 0 and budget.use().nbytes == 0
