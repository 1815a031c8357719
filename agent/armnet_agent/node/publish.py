"""Where a job's output lines and status transitions go besides the RobotJob: NATS, or nowhere.

The NATS library (``node.streams``: ``NatsLink``, ``JobStream``,
``OperatorInputsBridge``; see /work/AGENT-CONTRACT.md) is built separately.
This module is the agent's only door to it: with no NATS URL, or without that
library, every call is a no-op and jobs run exactly the same (their status is
written to the RobotJob either way).
"""

from __future__ import annotations

import importlib
import logging
from pathlib import Path
from typing import Any, Protocol

from armnet_agent.connector.inputs import OperatorInputs

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


def _streams() -> Any | None:
    try:
        return importlib.import_module("armnet_agent.node.streams")
    except ImportError:
        return None


def open_link(url: str | None, spool_dir: Path | None) -> Link:
    streams = _streams()
    if url is None:
        return NoLink()
    if streams is None:
        log.warning("--nats-url is set but this build has no NATS library (armnet_agent.node.streams); not publishing")
        return NoLink()
    link: Link = streams.NatsLink(streams.StreamSettings(url=url, spool_dir=spool_dir)).start()
    return link


def job_output(link: Link, namespace: str, job_uid: str) -> JobOutput:
    streams = _streams()
    if isinstance(link, NoLink) or streams is None:
        return NoOutput()
    output: JobOutput = streams.JobStream(link, namespace, job_uid)
    return output


def inputs_bridge(link: Link, inputs: OperatorInputs, *, namespace: str, job_uid: str, cell: str) -> Closable:
    streams = _streams()
    if isinstance(link, NoLink) or streams is None:
        return NoBridge()
    bridge: Closable = streams.OperatorInputsBridge(
        link, inputs, namespace=namespace, job_uid=job_uid, cell=cell
    ).start()
    return bridge
