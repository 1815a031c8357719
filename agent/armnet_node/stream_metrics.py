"""Prometheus view of the NATS link and the operator-input bridges, read at scrape time.

The link and the bridges keep plain counters (no prometheus import on the hot
path); this collector turns them into metrics when Prometheus scrapes, so there
is no second copy of a count to drift. Every inputs bridge counts into its link's
``input_counts`` as well as its own, so a job's bridge that closed keeps its counts.
Register one per agent process: ``registry.register(StreamsCollector(link))``.
"""

from __future__ import annotations

from collections.abc import Iterator

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from .streams import NatsLink


class StreamsCollector(Collector):
    def __init__(self, link: NatsLink) -> None:
        self.link = link

    def collect(self) -> Iterator[Metric]:
        link = self.link
        yield GaugeMetricFamily("armnet_agent_nats_connected",
                                "1 while the agent is connected to NATS and its stream is in place",
                                value=1.0 if link.connected else 0.0)
        yield CounterMetricFamily("armnet_agent_nats_published",
                                  "Lines (and status messages) JetStream acknowledged; resent duplicates it dropped included", value=link.published)
        yield CounterMetricFamily("armnet_agent_nats_dropped",
                                  "Lines (and status messages) lost: outbox and spool full, too large, refused, or unsent at stop",
                                  value=link.dropped)
        yield CounterMetricFamily("armnet_agent_nats_spooled",
                                  "Lines (and status messages) written to the disk spool while NATS was down or behind",
                                  value=link.spooled)
        yield GaugeMetricFamily("armnet_agent_nats_pending", "Lines (and status messages) waiting to be sent (memory and spool)",
                                value=link.pending)
        counts = link.input_counts
        inputs = CounterMetricFamily("armnet_agent_operator_inputs",
                                     "Operator inputs received on NATS, by result", labels=["result"])
        inputs.add_metric(["accepted"], counts.accepted)
        inputs.add_metric(["rejected"], counts.rejected)
        yield inputs
        yield CounterMetricFamily("armnet_agent_reset_notices",
                                  "Reset-wait notices sent to the cell operator's page (a wait's first notice and its "
                                  "repeats every 2 s while it waits)", value=counts.reset_notices)
