"""Fixtures the integration modules share: the operator's live bed (the bed itself is in operator_bed.py),
the simulated SO-101 and the agent's NATS link."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from armnet_node.streams import NatsLink
from armnet_sim import SimulatedCellProcess

from tests.integration.operator_bed import Bed, running_operator
from tests.support.sim_connector import connected_link, simulated_so101


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


@pytest.fixture(scope="module")
def sim() -> Iterator[SimulatedCellProcess]:
    """A simulated SO-101 (its arm on a pty), one per module: starting it takes a while."""
    with simulated_so101() as cell:
        yield cell


@pytest.fixture(scope="module")
def link(nats_server: str) -> Iterator[NatsLink]:
    """The agent's NATS link, connected, one per module; each test subscribes and closes what it uses."""
    with connected_link(nats_server) as connected:
        yield connected
