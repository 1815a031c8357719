"""Teleoperation, I/O part: sample a leader at a fixed rate and publish the latest action; send key events.

One asyncio loop: a ticker samples the leader every ``1/rate`` seconds and
publishes the sample (never a backlog: a slow tick is skipped, not queued), and
a reader turns terminal keys into events. ``stop_recording`` (Esc) also ends
the session after it was flushed to the server. A subscription to the job's
live Rerun packets keeps the follower's last reported state in the stats (plain
NATS, live only: an old state replayed would be wrong, not late).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Optional

from .errors import NatsUnreachable
from .logwire import decode, inbox_prefix
from .teleop import (
    STOP_RECORDING,
    action_payload,
    event_payload,
    follower_state,
    rerun_subject,
    teleop_subject,
)
from .viewer import packet_of

log = logging.getLogger(__name__)

Leader = Callable[[float], dict[str, float]]
"""Returns the leader's action for the time since the session started."""


@dataclass
class TeleopStats:
    """What the session sent so far, and the follower's state as the job last reported it."""

    actions: int = 0
    events: int = 0
    last_event: Optional[str] = None
    follower: Optional[dict[str, float]] = None
    follower_at: Optional[float] = None  # time.monotonic() when that state arrived


async def run_session(
    url: str, namespace: str, job_id: str, leader: Leader, *, rate_hz: float,
    events: asyncio.Queue[str], duration_s: Optional[float] = None,
    on_tick: Optional[Callable[[TeleopStats], None]] = None,
) -> TeleopStats:
    """Publish until Esc, ``duration_s``, or cancellation; returns what was sent."""
    import nats
    from nats.errors import NoServersError

    try:
        nc = await nats.connect(url, connect_timeout=3, max_reconnect_attempts=1,
                                reconnect_time_wait=0.25, inbox_prefix=inbox_prefix(namespace))
    except (TimeoutError, NoServersError, OSError) as exc:
        raise NatsUnreachable(f"cannot reach NATS at {url}: {exc}; teleop needs it") from exc
    nc.options["max_reconnect_attempts"] = -1
    action_subject = teleop_subject(namespace, job_id, "action")
    event_subject = teleop_subject(namespace, job_id, "event")
    stats = TeleopStats()

    async def on_packet(msg: Any) -> None:
        packet = packet_of(decode(msg.subject, msg.data, msg_id=None, stream_seq=0, stored_at=None))
        state = follower_state(packet) if packet is not None else None
        if state is not None:
            stats.follower, stats.follower_at = state, time.monotonic()

    await nc.subscribe(rerun_subject(namespace, job_id), cb=on_packet)
    await nc.flush()  # the server has the subscription before the first line says "no state yet"
    started = time.monotonic()
    period = 1.0 / rate_hz
    next_tick = started
    try:
        while duration_s is None or time.monotonic() - started < duration_s:
            while not events.empty():
                event = events.get_nowait()
                await nc.publish(event_subject, event_payload(event))
                stats.events += 1
                stats.last_event = event
                if event == STOP_RECORDING:
                    await nc.flush()
                    return stats
            await nc.publish(action_subject, action_payload(leader(time.monotonic() - started)))
            stats.actions += 1
            if on_tick is not None:
                on_tick(stats)
            next_tick += period
            now = time.monotonic()
            if next_tick < now:  # fell behind: skip the missed samples, latest value only
                next_tick = now + period
            await asyncio.sleep(next_tick - now)
        await nc.flush()
        return stats
    finally:
        await nc.close()


def lerobot_leader(port: str, leader_id: Optional[str]) -> tuple[Leader, Callable[[], None]]:
    """A real SO-101 leader arm through LeRobot (``lerobot`` must be installed), and its disconnect."""
    try:
        from lerobot.teleoperators.so_leader import SO101Leader, SO101LeaderConfig
    except ImportError as exc:
        raise RuntimeError(
            "a leader arm needs LeRobot: pip install 'armnet-runtime[lerobot]' (or use --leader sim)"
        ) from exc
    arm: Any = SO101Leader(SO101LeaderConfig(port=port, id=leader_id or "leader"))
    arm.connect()

    def sample(_t: float) -> dict[str, float]:
        return {str(k): float(v) for k, v in arm.get_action().items()}

    return sample, arm.disconnect
