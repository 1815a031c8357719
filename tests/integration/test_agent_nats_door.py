"""The agent's door to NATS: a real link when a URL is given, its metrics on the agent's registry."""

from __future__ import annotations

import time

import pytest
from armnet_node.metrics import AgentMetrics
from armnet_node.publish import NoLink, NoOutput, job_output, open_link, register_metrics
from prometheus_client import generate_latest

pytestmark = pytest.mark.integration


def test_without_a_url_nothing_is_published_and_no_stream_metric_is_registered(tmp_path) -> None:
    link = open_link(None, tmp_path / "spool")
    metrics = AgentMetrics()
    register_metrics(link, metrics.registry)
    assert isinstance(link, NoLink)
    assert isinstance(job_output(link, "team-a", "uid-1"), NoOutput)
    assert "armnet_agent_nats_connected" not in generate_latest(metrics.registry).decode()


def test_with_a_url_the_link_connects_and_its_metrics_sit_next_to_the_agents(nats_server: str, tmp_path) -> None:
    link = open_link(nats_server, tmp_path / "spool")
    try:
        metrics = AgentMetrics()
        register_metrics(link, metrics.registry)
        deadline = time.monotonic() + 20
        while "armnet_agent_nats_connected 1.0" not in generate_latest(metrics.registry).decode():
            assert time.monotonic() < deadline, generate_latest(metrics.registry).decode()
            time.sleep(0.1)
        text = generate_latest(metrics.registry).decode()
        assert "armnet_agent_jobs_started_total" in text and "armnet_agent_nats_dropped_total" in text
    finally:
        link.stop()
