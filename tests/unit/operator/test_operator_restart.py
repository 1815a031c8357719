"""When kopf's reactor fails, the operator starts again in-process with a backoff, then gives up."""

from __future__ import annotations

import pytest
from armnet_operator.cli import MAX_RESTARTS, restart_after

pytestmark = pytest.mark.unit


def test_the_first_failures_restart_quickly_and_back_off_to_at_most_30_seconds() -> None:
    waits = [restart_after(n) for n in range(1, MAX_RESTARTS + 1)]

    assert waits[0] == 1.0
    assert waits == sorted(waits) and all(w is not None and w <= 30.0 for w in waits)


def test_after_too_many_failures_in_a_row_the_process_exits_for_its_deployment_to_restart_it() -> None:
    assert restart_after(MAX_RESTARTS + 1) is None
