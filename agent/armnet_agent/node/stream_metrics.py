"""Prometheus view of the NATS link and the operator-input bridges, read at scrape time.

The link and the bridges keep plain counters (no prometheus import on the hot
path); this collector turns them into metrics when Prometheus scrapes, so there
is no second copy of a count to drift. Register one per agent process:
``registry.register(StreamsCollector(link, bridges=lambda: [...]))``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from .inputs_bridge import OperatorInputsBridge
from .streams import NatsLink


class StreamsCollector(Collector):
    def __init__(self, link: NatsLink,
                 bridges: Callable[[], Iterable[OperatorInputsBridge]] = lambda: ()) -> None:
        self.link = link
        self.bridges = bridges
        self._inputs_retired = (0, 0, 0)

    def retire(self, bridge: OperatorInputsBridge) -> None:
        """Keep a closed bridge's counts (counters never go down when a job ends)."""
        accepted, rejected, notices = self._inputs_retired
        self._inputs_retired = (accepted + bridge.accepted, rejected + bridge.rejected,
                                notices + bridge.reset_notices_sent)

    def collect(self) -> Iterator[Metric]:
        link = self.link
        yield GaugeMetricFamily("armnet_agent_nats_connected",
                                "1 while the agent is connected to NATS and its stream is in place",
                                value=1.0 if link.connected else 0.0)
        yield CounterMetricFamily("armnet_agent_nats_published",
                                  "Messages JetStream acknowledged (resent duplicates it dropped included)", value=link.published)
        yield CounterMetricFamily("armnet_agent_nats_dropped",
                                  "Messages lost: outbox and spool full, too large, refused, or unsent at stop",
                                  value=link.dropped)
        yield CounterMetricFamily("armnet_agent_nats_spooled",
                                  "Messages written to the disk spool while NATS was down or behind",
                                  value=link.spooled)
        yield GaugeMetricFamily("armnet_agent_nats_pending", "Messages waiting to be sent (memory and spool)",
                                value=link.pending)
        accepted, rejected, notices = self._inputs_retired
        for bridge in self.bridges():
            accepted += bridge.accepted
            rejected += bridge.rejected
            notices += bridge.reset_notices_sent
        inputs = CounterMetricFamily("armnet_agent_operator_inputs",
                                     "Operator inputs received on NATS, by result", labels=["result"])
        inputs.add_metric(["accepted"], accepted)
        inputs.add_metric(["rejected"], rejected)
        yield inputs
        yield CounterMetricFamily("armnet_agent_reset_notices",
                                  "Reset-wait notices sent to the cell operator's page (a wait's first notice and its "
                                  "repeats every 2 s while it waits)", value=notices)
