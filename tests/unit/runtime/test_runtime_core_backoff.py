"""armnet_core.backoff: the one retry policy of every loop."""

from __future__ import annotations

import pytest
from armnet_core.backoff import BackoffPolicy


def test_the_wait_doubles_from_first_to_max_and_a_success_starts_over() -> None:
    backoff = BackoffPolicy(first_s=0.2, max_s=1.0).start()
    assert not backoff.failing and backoff.current_s == 0.0
    assert [backoff.failed() for _ in range(5)] == [0.2, 0.4, 0.8, 1.0, 1.0]
    assert backoff.failing and backoff.current_s == 1.0
    backoff.succeeded()
    assert not backoff.failing and backoff.failed() == 0.2


def test_a_long_outage_stays_at_the_max_without_overflowing() -> None:
    policy = BackoffPolicy(first_s=1.0, max_s=60.0)
    assert policy.delay(10_000) == 60.0
    assert policy.delay(0) == policy.delay(-3) == 0.0


@pytest.mark.parametrize(("first", "most"), [(0.0, 1.0), (2.0, 1.0), (-1.0, 5.0)])
def test_a_policy_that_cannot_grow_from_first_to_max_is_refused(first: float, most: float) -> None:
    with pytest.raises(ValueError, match="0 < first_s <= max_s"):
        BackoffPolicy(first_s=first, max_s=most)
