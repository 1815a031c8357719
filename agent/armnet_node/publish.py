"""Where a job's output lines and status transitions go besides the RobotJob: NATS, or nowhere.

The NATS library (``node.streams``: ``NatsLink``, ``JobStream``,
``OperatorInputsBridge``; docs/streams.md) does the work. This module is the
agent's only door to it: with no NATS URL every call is a no-op and jobs run
exactly the same (their status is written to the RobotJob either way).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

from armnet_connector.inputs import OperatorInputs
from prometheus_client import CollectorRegistry

from armnet_node import health, streams
from armnet_node.inputs_bridge import OperatorInputsBridge
from armnet_node.sidecar_inputs import SidecarInputs
from armnet_node.stream_metrics import StreamsCollector

log = logging.getLogger(__name__)


class JobOutput(Protocol):
    def line(self, kind: str, seq: int, text: str) -> None: ...

    def status(self, phase: str, detail: dict[str, Any]) -> None: ...


class Closable(Protocol):
    def close(self) -> None: ...


class Link(Protocol):
    @property
    def connected(self) -> bool: ...

    def stop(self, timeout_s: float = 5.0) -> None: ...


class NoLink:
    """NATS disabled: nothing is published, no operator input arrives over the network."""

    connected = False

    def stop(self, timeout_s: float = 5.0) -> None:
        return None


class NoOutput:
    def line(self, kind: str, seq: int, text: str) -> None:
        return None

    def status(self, phase: str, detail: dict[str, Any]) -> None:
        return None


class NoBridge:
    def close(self) -> None:
        return None


def open_link(url: str | None, spool_dir: Path | None) -> Link:
    if url is None:
        return NoLink()
    link: Link = streams.NatsLink(streams.StreamSettings(url=url, spool_dir=spool_dir)).start()
    return link


def streams_probe(link: Link) -> health.StreamsProbe:
    """What the Cells' ``StreamsConnected`` condition says about this link."""
    if not isinstance(link, streams.NatsLink) or not link.enabled:
        return health.StreamsProbe(configured=False)
    return health.StreamsProbe(configured=True, connected=link.connected, server=server_of(link.settings.url or ""))


def server_of(url: str) -> str:
    """``host:port`` of a NATS URL, without the user and password it may carry."""
    try:
        parts = urlsplit(url)
        host, port = parts.hostname, parts.port
    except ValueError:
        return "its URL"
    if not host:
        return "its URL"
    return f"{host}:{port}" if port else host


def register_metrics(link: Link, registry: CollectorRegistry) -> None:
    """The stream's own metrics (connected, published, dropped, spooled, pending, inputs)."""
    if isinstance(link, streams.NatsLink):
        registry.register(StreamsCollector(link))


def job_output(link: Link, namespace: str, job_uid: str) -> JobOutput:
    if not isinstance(link, streams.NatsLink):  # NoLink: NATS is off
        return NoOutput()
    output: JobOutput = streams.JobStream(link, namespace, job_uid)
    return output


def telemetry_notifier(link: Link) -> streams.NatsLink | None:
    """The link's core-NATS notices (telemetry for the cell operator's page), or None without NATS."""
    return link if isinstance(link, streams.NatsLink) else None


def inputs_bridge(link: Link, inputs: OperatorInputs | SidecarInputs, *, namespace: str, job_uid: str, cell: str,
                  active_rollout: Callable[[], int | None] | None = None,
                  on_verdict: Callable[[bool, str, int | None], None] | None = None,
                  accepts_verdict: Callable[[int | None], bool] | None = None,
                  on_overrule: Callable[[bool, str, int, datetime], bool] | None = None) -> Closable:
    if not isinstance(link, streams.NatsLink):  # NoLink: NATS is off
        return NoBridge()
    bridge: Closable = OperatorInputsBridge(
        link, inputs, namespace=namespace, job_uid=job_uid, cell=cell, active_rollout=active_rollout,
        on_verdict=on_verdict, accepts_verdict=accepts_verdict, on_overrule=on_overrule,
    ).start()
    return bridge
