"""The node agent lists its job containers at most once a pass period, however often it wakes.

A pass runs on every watch event as well as on its timer; listing the engine each time
made Podman start a ``runc state`` per running container several times a second.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, cast

import pytest
from armnet_node.agent import AgentSettings, NodeAgent
from armnet_node.metrics import AgentMetrics

pytestmark = pytest.mark.unit


class ListingLauncher:
    """A launcher that counts the lists it answers (the agent's only call to it here)."""

    kind = "container"
    secrets_by_ref = False

    def __init__(self) -> None:
        self.lists = 0

    def running(self) -> dict[str, Any]:
        self.lists += 1
        return {f"uid-{self.lists}": {"Labels": {}}}


def agent(tmp_path: Path, launcher: ListingLauncher, pass_period: float) -> NodeAgent:
    settings = AgentSettings(node_name="n1", state_dir=tmp_path, pass_period=pass_period)
    return NodeAgent(settings, kube=cast(Any, None), launcher=cast(Any, launcher), metrics=AgentMetrics(),
                     link=cast(Any, None))


def test_passes_within_one_period_share_one_list(tmp_path: Path) -> None:
    launcher = ListingLauncher()
    node = agent(tmp_path, launcher, pass_period=60.0)

    rows = [node._containers() for _ in range(5)]

    assert launcher.lists == 1
    assert all(r == {"uid-1": {"Labels": {}}} for r in rows)


def test_a_pass_after_the_period_lists_again(tmp_path: Path) -> None:
    launcher = ListingLauncher()
    node = agent(tmp_path, launcher, pass_period=0.05)

    first = node._containers()
    time.sleep(0.06)
    second = node._containers()

    assert launcher.lists == 2
    assert first != second
