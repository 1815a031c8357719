"""``--image`` without a reachable engine: a clear message, never a trace."""

from __future__ import annotations

from pathlib import Path

import pytest
from armnet_launch.container import EngineUnavailable, connect_engine, engine_url

pytestmark = pytest.mark.unit


def test_docker_host_wins_over_the_podman_socket() -> None:
    assert engine_url({"DOCKER_HOST": "tcp://127.0.0.1:2375"}) == "tcp://127.0.0.1:2375"
    assert engine_url({}) == "unix:///run/podman/podman.sock"


def test_an_engine_socket_nobody_serves_says_how_to_start_one(tmp_path: Path) -> None:
    with pytest.raises(EngineUnavailable) as caught:
        connect_engine(f"unix://{tmp_path / 'nothing.sock'}")
    message = str(caught.value)
    assert "no container engine answers" in message
    assert "podman system service" in message and "drop --image" in message
