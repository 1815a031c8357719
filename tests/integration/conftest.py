"""Fixtures of the operator's live tests (the bed itself is in operator_bed.py)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from tests.integration.operator_bed import Bed, running_operator


@pytest.fixture
def bed(k8s: Any, namespace: str) -> Iterator[Bed]:
    """The test's hands on the cluster, heartbeating the Cells it made until the test ends."""
    bed = Bed(k8s, namespace)
    try:
        yield bed
    finally:
        bed.close()


@pytest.fixture
def operator(k8s: Any, namespace: str, monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """The operator, in-process, watching the test's namespace; its controller."""
    with running_operator(k8s, namespace, monkeypatch) as controller:
        yield controller
