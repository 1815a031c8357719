"""The FMS's NATS side: hears ``fms.*.reset.requested`` notices and publishes operator inputs.

Core NATS (the agent's bridge subscribes the same subjects with core NATS);
nats-py reconnects on its own. A publish while NATS is down raises, so the
operator's click fails visibly instead of being lost quietly.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from typing import Any, Protocol

log = logging.getLogger(__name__)

RESET_REQUESTED = "fms.*.reset.requested"
TELEMETRY = "telemetry.>"
TELEMETRY_PENDING_BYTES = 8 * 1024 * 1024
"""Telemetry the NATS client holds for the FMS at most: past it, a flood is dropped (and counted), not queued."""
TELEMETRY_PENDING_MSGS = 2000


class OperatorBus(Protocol):
    """Carries operator inputs to jobs and reset notices back: NATS (``Bus``) or a local run (``local``)."""

    @property
    def connected(self) -> bool: ...
    async def start(self, on_reset_requested: Callable[[str, dict[str, Any]], None]) -> None: ...
    async def publish(self, subject: str, data: bytes) -> None: ...
    async def close(self) -> None: ...


class BusUnavailable(RuntimeError):
    """NATS cannot take the message now; the operator should try again."""


class Bus:
    """``on_telemetry(subject, data)`` hears the agents' ``telemetry.>`` (frames, servo readings) when given.

    ``on_dropped()`` is called for each telemetry message the NATS client dropped
    because the FMS fell behind (its pending limit was reached).
    """

    def __init__(self, url: str, on_telemetry: Callable[[str, bytes], object] | None = None,
                 on_dropped: Callable[[], object] | None = None,
                 pending_bytes_limit: int = TELEMETRY_PENDING_BYTES) -> None:
        self.url = url
        self._pending_bytes_limit = pending_bytes_limit
        self._on_telemetry = on_telemetry
        self._on_dropped = on_dropped
        self._telemetry_sub: Any = None
        self._nc: Any = None

    async def start(self, on_reset_requested: Callable[[str, dict[str, Any]], None]) -> None:
        import nats

        async def on_notice(msg: Any) -> None:
            parts = msg.subject.split(".")
            if len(parts) != 4 or len(msg.data) > 4096:
                return
            try:
                notice = json.loads(msg.data)
            except ValueError:
                return
            if isinstance(notice, dict):
                on_reset_requested(parts[1], notice)

        self._nc = await nats.connect(self.url, max_reconnect_attempts=-1, reconnect_time_wait=1,
                                      name="armnet-fms", error_cb=self._on_error)
        await self._nc.subscribe(RESET_REQUESTED, cb=on_notice)
        if self._on_telemetry is not None:
            handler = self._on_telemetry

            async def on_telemetry(msg: Any) -> None:
                handler(msg.subject, msg.data)

            self._telemetry_sub = await self._nc.subscribe(
                TELEMETRY, cb=on_telemetry, pending_bytes_limit=self._pending_bytes_limit,
                pending_msgs_limit=TELEMETRY_PENDING_MSGS)
        await self._nc.flush()

    async def _on_error(self, error: Exception) -> None:
        from nats.errors import SlowConsumerError

        if isinstance(error, SlowConsumerError):
            if error.sub is self._telemetry_sub and self._on_dropped is not None:
                self._on_dropped()  # nats-py reports each message it drops for a full subscriber
            return
        log.warning("NATS: %s", str(error)[:200])

    @property
    def connected(self) -> bool:
        return bool(self._nc is not None and self._nc.is_connected)

    async def publish(self, subject: str, data: bytes) -> None:
        if not self.connected:
            raise BusUnavailable(f"NATS at {self.url} is not connected; nothing was sent, try again")
        await self._nc.publish(subject, data)
        await self._nc.flush(timeout=5)

    async def close(self) -> None:
        if self._nc is not None:
            await self._nc.drain()
            self._nc = None
