"""Heartbeats of a client that follows a non-detached job (``JobSpec.detach=False``).

The SDK's rule (``JobSpec.detach``): losing the following client requests graceful cancellation.
Only the agent can enforce it in a way that survives a client crash, so the
client's part is small: while it follows, publish ``{"at": <UTC time>,
"client": <host:pid>}`` every ``interval_s`` on
``clients.<namespace>.<jobId>.heartbeat`` (plain NATS: a heartbeat is only
worth anything now; docs/streams.md). The agent watches a job only when its
submitter declared a follower (the annotation ``armnet.io/follower-timeout-seconds``,
``mapping.follower_metadata``) and cancels it when no beat arrived for that
window (docs/agent.md, "Followed jobs").
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import socket
import threading
from datetime import datetime, timezone
from typing import Optional

from armnet_core.times import micro_time

from .logwire import inbox_prefix, job_subjects

log = logging.getLogger(__name__)

DEFAULT_INTERVAL_S = 2.0


def heartbeat_subject(namespace: str, job_id: str) -> str:
    job_subjects(namespace, job_id)  # the same token checks
    return f"clients.{namespace}.{job_id}.heartbeat"


def heartbeat_payload(now: datetime, client: str) -> bytes:
    return json.dumps({"at": micro_time(now), "client": client}).encode()


class HeartbeatSender:
    """A daemon thread with its own loop, so heartbeats go out while the caller prints or blocks."""

    def __init__(self, url: str, namespace: str, job_id: str,
                 interval_s: float = DEFAULT_INTERVAL_S) -> None:
        self.url = url
        self.subject = heartbeat_subject(namespace, job_id)
        self.inbox_prefix = inbox_prefix(namespace)
        self.interval_s = interval_s
        self.client = f"{socket.gethostname()}:{os.getpid()}"
        self.sent = 0
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    def start(self) -> HeartbeatSender:
        self._thread = threading.Thread(target=self._run, name="armnet-heartbeat", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _run(self) -> None:
        try:
            asyncio.run(self._beat())
        except Exception as exc:  # noqa: BLE001 - a lost heartbeat must never break the follow
            log.warning("heartbeats to %s stopped: %s; a non-detached job may be cancelled", self.url, exc)

    async def _beat(self) -> None:
        import nats

        async def quiet(_exc: Exception) -> None:
            return None

        nc = await nats.connect(self.url, connect_timeout=3, max_reconnect_attempts=1,
                                reconnect_time_wait=0.25, error_cb=quiet, inbox_prefix=self.inbox_prefix)
        nc.options["max_reconnect_attempts"] = -1
        try:
            while not self._stop.is_set():
                try:
                    await nc.publish(self.subject, heartbeat_payload(datetime.now(timezone.utc), self.client))  # noqa: UP017
                    await nc.flush(timeout=1)
                    self.sent += 1
                except Exception as exc:  # noqa: BLE001 - reconnecting: the next beat tries again
                    log.debug("heartbeat not sent: %s", exc)
                await asyncio.get_running_loop().run_in_executor(None, self._stop.wait, self.interval_s)
        finally:
            await nc.close()
