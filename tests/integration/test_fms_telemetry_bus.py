"""The FMS's telemetry subscription on a real nats-server: a flood is dropped and counted, never queued without bound."""

from __future__ import annotations

import asyncio
import time

import pytest
from armnet_fms.bus import Bus
from armnet_fms.telemetry import TelemetryStore

pytestmark = pytest.mark.integration

JPEG = b"\xff\xd8\xff\xe0" + b"\x00" * 4096


def test_a_telemetry_flood_beyond_the_pending_limit_is_dropped_and_counted(nats_server: str) -> None:
    async def body() -> TelemetryStore:
        import nats

        store = TelemetryStore(known_cells=lambda: {"cell-1"})

        def slow_accept(subject: str, data: bytes) -> None:
            time.sleep(0.002)  # an FMS that falls behind: every message waits on the one before
            store.accept(subject, data, time.time())

        bus = Bus(nats_server, on_telemetry=slow_accept, on_dropped=store.count_dropped,
                  pending_bytes_limit=64 * 1024)
        await bus.start(lambda cell, notice: None)
        publisher = await nats.connect(nats_server)
        for _ in range(2000):
            await publisher.publish("telemetry.cell-1.camera.front", JPEG)
        await publisher.flush()
        await publisher.close()
        deadline = time.monotonic() + 15
        while store.kept + store.dropped < 2000 and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        await bus.close()
        return store

    store = asyncio.run(asyncio.wait_for(body(), 30))
    assert store.dropped > 0
    assert store.kept + store.dropped == 2000
