"""The link's counters are what Prometheus scrapes."""

from __future__ import annotations

import pytest
from armnet_connector.inputs import LocalOperatorInputs
from armnet_node.inputs_bridge import OperatorInputsBridge
from armnet_node.stream_metrics import StreamsCollector
from armnet_node.streams import NatsLink, StreamSettings
from prometheus_client import CollectorRegistry, generate_latest

pytestmark = pytest.mark.unit


def scrape(link: NatsLink) -> str:
    registry = CollectorRegistry()
    registry.register(StreamsCollector(link))
    return generate_latest(registry).decode()


def test_a_scrape_shows_the_link_and_its_bridges_counters() -> None:
    link = NatsLink(StreamSettings(url=None))
    bridge = OperatorInputsBridge(link, LocalOperatorInputs(), namespace="ns", job_uid="uid", cell="cell")
    bridge._on_message("teleop.ns.uid.event", b'{"event": "next_episode"}')
    bridge._on_message("teleop.ns.uid.event", b"garbage")
    bridge.announce_reset_waiting()

    text = scrape(link)

    assert "armnet_agent_nats_connected 0.0" in text
    assert "armnet_agent_nats_dropped_total 0.0" in text
    assert 'armnet_agent_operator_inputs_total{result="accepted"} 1.0' in text
    assert 'armnet_agent_operator_inputs_total{result="rejected"} 1.0' in text
    assert "armnet_agent_reset_notices_total 1.0" in text


def test_a_closed_bridges_counts_stay_and_every_bridge_on_the_link_adds_to_them() -> None:
    link = NatsLink(StreamSettings(url=None))
    first = OperatorInputsBridge(link, LocalOperatorInputs(), namespace="ns", job_uid="a", cell="cell")
    first._on_message("fms.cell.stop", b"[]")
    first.close()
    second = OperatorInputsBridge(link, LocalOperatorInputs(), namespace="ns", job_uid="b", cell="cell")
    second._on_message("fms.cell.stop", b"{}")
    assert 'armnet_agent_operator_inputs_total{result="rejected"} 2.0' in scrape(link)
