"""The link's counters are what Prometheus scrapes."""

from __future__ import annotations

import pytest
from armnet_agent.connector.inputs import LocalOperatorInputs
from armnet_agent.node.inputs_bridge import OperatorInputsBridge
from armnet_agent.node.stream_metrics import StreamsCollector
from armnet_agent.node.streams import NatsLink, StreamSettings
from prometheus_client import CollectorRegistry, generate_latest

pytestmark = pytest.mark.unit


def test_a_scrape_shows_the_link_and_the_bridges_counters() -> None:
    link = NatsLink(StreamSettings(url=None))
    bridge = OperatorInputsBridge(link, LocalOperatorInputs(), namespace="ns", job_uid="uid", cell="cell")
    bridge._on_message("teleop.ns.uid.event", b'{"event": "next_episode"}')
    bridge._on_message("teleop.ns.uid.event", b"garbage")
    bridge.announce_reset_waiting()
    registry = CollectorRegistry()
    registry.register(StreamsCollector(link, bridges=lambda: [bridge]))

    text = generate_latest(registry).decode()

    assert "armnet_agent_nats_connected 0.0" in text
    assert "armnet_agent_nats_dropped_total 0.0" in text
    assert 'armnet_agent_operator_inputs_total{result="accepted"} 1.0' in text
    assert 'armnet_agent_operator_inputs_total{result="rejected"} 1.0' in text
    assert "armnet_agent_reset_notices_total 1.0" in text


def test_a_retired_bridge_keeps_its_counts() -> None:
    link = NatsLink(StreamSettings(url=None))
    bridge = OperatorInputsBridge(link, LocalOperatorInputs(), namespace="ns", job_uid="uid", cell="cell")
    bridge._on_message("fms.cell.stop", b"[]")
    collector = StreamsCollector(link)
    collector.retire(bridge)
    registry = CollectorRegistry()
    registry.register(collector)
    assert 'armnet_agent_operator_inputs_total{result="rejected"} 1.0' in generate_latest(registry).decode()
