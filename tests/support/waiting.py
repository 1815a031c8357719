"""Waiting in a test for what another thread or process does: poll, then fail the test saying what did not happen."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def wait_for(condition: Callable[[], Any], timeout: float = 30, what: str = "condition", every: float = 0.05,
             why: Callable[[], str] | None = None) -> Any:
    """The first truthy value ``condition`` returns, asked every ``every`` seconds; after ``timeout``
    seconds without one, the test fails naming ``what`` it waited for (and what ``why`` says of it)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            detail = f"\n{why()}" if why is not None else ""
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}{detail}")
        time.sleep(every)
