"""Cancel a non-detached job whose following client went away (docs/agent.md, "Followed jobs").

The SDK's rule for ``JobSpec.detach=False``: losing the client requests
graceful cancellation. Only the agent can enforce that in a way that survives a
client crash (``kill -9``, a laptop lid closing), so the client's part is small:

- when it submits a job it will follow (``execute()``, ``armnet submit`` without
  ``--detach``) it sets the annotation :data:`FOLLOWER_TIMEOUT_ANNOTATION` (``follower_rule``) on the
  RobotJob, whose value is the window in seconds;
- while it follows, it publishes a heartbeat every 2 s on
  ``clients.<namespace>.<jobId>.heartbeat`` (plain NATS).

A job without the annotation is never watched: ``kubectl apply`` of a RobotJob
(``detach`` defaults to false in the CRD) has no follower, and cancelling it
for missing heartbeats would cancel every job of the primary interface. A job
with ``detach: true`` is never watched either, whatever its annotations say.

The clock starts when the job runs on this agent (also after an agent restart
adopted it: a fresh window) and pauses while the agent itself is not connected
to NATS: beats the agent could not hear are never the client's fault.

The rule (``follower_rule``: annotation, window, clock, message) is pure;
:class:`FollowerGuard` subscribes and checks the clock on a thread of its own.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from armnet_core.api import FOLLOWER_TIMEOUT_ANNOTATION

from armnet_node.follower_rule import (
    FollowerClock,
    heartbeat_subject,
    lost_follower_message,
)
from armnet_node.publish import NoLink

log = logging.getLogger(__name__)


class FollowerGuard:
    """Calls ``on_lost(message)`` once when the job's follower stayed silent past the window."""

    def __init__(
        self,
        link: Any,
        namespace: str,
        job_uid: str,
        window_s: float,
        on_lost: Callable[[str], None],
        *,
        check_every_s: float = 0.5,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.link = link
        self.subject = heartbeat_subject(namespace, job_uid)
        self.on_lost = on_lost
        self.check_every_s = check_every_s
        self._now = clock
        self.clock = FollowerClock(window_s, clock())
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._subscription: Any = None
        self._thread = threading.Thread(target=self._watch, name=f"armnet-follower-{job_uid[:8]}", daemon=True)

    def start(self) -> FollowerGuard:
        self._subscription = self.link.subscribe(self.subject, self._on_beat)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._subscription is not None:
            self._subscription.close()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(2)

    def _on_beat(self, _subject: str, _data: bytes) -> None:
        # Any message counts: only the job's namespace may publish here (NATS permissions),
        # and the content (time, client id) is for people reading the subject.
        with self._lock:
            self.clock.beat(self._now())

    def _watch(self) -> None:
        while not self._stop.wait(self.check_every_s):
            now = self._now()
            with self._lock:
                if not self.link.connected:
                    self.clock.pause(now)
                    continue
                if not self.clock.expired(now):
                    continue
                message = lost_follower_message(self.clock.window_s, self.clock.silence(now))
            log.warning("%s: %s", self.subject, message)
            self.on_lost(message)
            return


def guard_follower(
    link: Any, namespace: str, job_uid: str, window_s: float | None, on_lost: Callable[[str], None]
) -> FollowerGuard | None:
    """A started guard for a followed job; None when none is declared or the agent has no NATS."""
    if window_s is None:
        return None
    if isinstance(link, NoLink):
        log.warning("job %s/%s declares a follower (%s) but this agent has no NATS (--nats-url): "
                    "its heartbeats cannot be heard, so it runs as if detached", namespace, job_uid,
                    FOLLOWER_TIMEOUT_ANNOTATION)
        return None
    return FollowerGuard(link, namespace, job_uid, window_s, on_lost).start()
