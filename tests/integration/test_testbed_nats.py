"""The test bed's NATS is real JetStream: durable consumers resume and replay after reconnects."""

from __future__ import annotations

import asyncio
import uuid

import nats
import pytest
from armnet_testbed.natsd import NatsServer
from nats.js.api import ConsumerConfig, DeliverPolicy

pytestmark = pytest.mark.integration


async def _publish(js: object, subject: str, count: int) -> None:
    for i in range(count):
        await js.publish(subject, f"line {i}".encode())  # type: ignore[attr-defined]


async def _fetch(sub: object, count: int) -> list[str]:
    msgs = await sub.fetch(count, timeout=5)  # type: ignore[attr-defined]
    for msg in msgs:
        # Acknowledged by the server before anything goes on: a plain ack() is only sent, and a
        # restart right after it (the second test) redelivered the message it had not processed.
        await msg.ack_sync()
    return [m.data.decode() for m in msgs]


def test_a_durable_consumer_resumes_after_the_client_reconnects(nats_server: str) -> None:
    stream = f"LOGS_{uuid.uuid4().hex[:8]}"
    subject = f"replay.{stream}.job.stdout"

    async def scenario() -> tuple[list[str], list[str], list[str]]:
        nc = await nats.connect(nats_server)
        js = nc.jetstream()
        await js.add_stream(name=stream, subjects=[f"replay.{stream}.>"])
        await _publish(js, subject, 5)
        first = await _fetch(await js.pull_subscribe(subject, durable="reader", stream=stream), 2)
        await nc.close()

        nc = await nats.connect(nats_server)
        js = nc.jetstream()
        rest = await _fetch(await js.pull_subscribe(subject, durable="reader", stream=stream), 3)
        replay_sub = await js.subscribe(subject, stream=stream, ordered_consumer=True,
                                        config=ConsumerConfig(deliver_policy=DeliverPolicy.ALL))
        replay = [(await replay_sub.next_msg(timeout=5)).data.decode() for _ in range(5)]
        await nc.close()
        return first, rest, replay

    first, rest, replay = asyncio.run(scenario())

    assert first == ["line 0", "line 1"]
    assert rest == ["line 2", "line 3", "line 4"]
    assert replay == [f"line {i}" for i in range(5)]


def test_jetstream_keeps_messages_and_consumers_across_a_server_restart() -> None:
    server = NatsServer().start()
    try:
        async def scenario() -> tuple[list[str], list[str]]:
            reconnected = asyncio.Event()

            async def on_reconnect() -> None:
                reconnected.set()

            nc = await nats.connect(server.url, max_reconnect_attempts=-1, reconnect_time_wait=0.2,
                                    reconnected_cb=on_reconnect)
            js = nc.jetstream()
            await js.add_stream(name="EVENTS", subjects=["events.>"])
            await _publish(js, "events.cell-1", 4)
            sub = await js.pull_subscribe("events.cell-1", durable="agent", stream="EVENTS")
            before = await _fetch(sub, 1)

            await asyncio.to_thread(server.restart)
            await asyncio.wait_for(reconnected.wait(), timeout=20)
            after = await _fetch(sub, 3)
            await nc.close()
            return before, after

        before, after = asyncio.run(scenario())
    finally:
        server.stop()

    assert before == ["line 0"]
    assert after == ["line 1", "line 2", "line 3"]
