"""Operator inputs from NATS to one running job's connector: teleop, outcome, stop, reset confirmation.

Anyone who can publish on a subject can send these, so every message is
hostile until checked: bounded size, one JSON object, exact fields and types
(pydantic, extra fields refused). A bad message is dropped, counted in
``rejected`` and logged at most once per interval; a good one is applied to the
job's :class:`~armnet_connector.inputs.OperatorInputs`, which decides what
it means (a reset confirmation with no reset waiting is dropped there). So that
the cell's operator knows when a confirmation counts, the bridge announces on
``fms.<cell>.reset.requested`` each time the job's reset starts to wait, with a
request id; a confirmation naming another request is dropped here. The notice is
core NATS (not stored), so one sent while the link reconnects, or before the
page lists the cell, would be lost and the page would show no prompt until the
reset timed out: the same notice (same request id, with the seconds waited so
far) is repeated every ``REANNOUNCE_S`` while that wait lasts. This module never
touches hardware.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
import unicodedata
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Annotated, Literal

from armnet_connector.inputs import LocalOperatorInputs, OperatorInputs
from armnet_connector.ratelog import RateLimitedLog
from armnet_core.times import micro_time, parse_time
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator

from .sidecar_inputs import SidecarInputs
from .streams import NatsLink, Subscription, fms_subject, teleop_subject

log = logging.getLogger(__name__)

MAX_INPUT_BYTES = 16 * 1024
#: How often a waiting reset's notice is repeated (the page's prompt appears at most this late after a lost notice).
REANNOUNCE_S = 2.0
MAX_ACTION_MOTORS = 64
Name = Annotated[str, Field(max_length=128)]


def _printable(name: str) -> str:
    if any(unicodedata.category(c)[0] == "C" for c in name):
        raise ValueError("an operator name must not hold control or format characters")
    return name


#: Who sent an input: recorded in the job's status (``status.rollouts[].markedBy``) and logs.
OperatorName = Annotated[str, Field(min_length=1, max_length=128), AfterValidator(_printable)]


class _Input(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class TeleopAction(_Input):
    """``{"action": {motor: value, ...}}``; null clears the action. Values are finite numbers."""

    action: dict[Name, float] | None = Field(max_length=MAX_ACTION_MOTORS)

    @field_validator("action")
    @classmethod
    def _finite(cls, action: dict[str, float] | None) -> dict[str, float] | None:
        if action is not None and not all(math.isfinite(v) for v in action.values()):
            raise ValueError("teleop action values must be finite numbers")
        return action


class TeleopEvent(_Input):
    event: Literal["next_episode", "rerecord_episode", "stop_recording"]


class ResetConfirm(_Input):
    """``request`` names the reset confirmed (the notice's ``request``); null: whichever reset waits."""

    by: OperatorName
    request: int | Name | None = None


class Outcome(_Input):
    """``rollout`` names the rollout judged (the FMS sends the index it showed); null: whichever is active."""

    success: bool
    by: OperatorName
    rollout: int | None = None


class Overrule(_Input):
    """A cell operator's outcome for a rollout the monitor judged, from the page's list of verdicts:
    ``rollout`` and ``startedAt`` as ``status.rollouts`` has them. Recorded, never sent to the job."""

    success: bool
    by: OperatorName
    rollout: int = Field(ge=0)
    started_at: str = Field(alias="startedAt", min_length=1, max_length=64)


class Stop(_Input):
    by: OperatorName
    reason: str = Field(default="", max_length=1024)


def reset_request_id(job_uid: str, announced_at: str) -> str:
    """The name of one reset wait: the job and when it was announced (at most 128 characters)."""
    return f"{job_uid}@{announced_at}"[:128]


@dataclass(frozen=True)
class _ResetNotice:
    """The announcement of one reset wait, repeated as it was while that wait lasts."""

    request: str
    at: str
    wait: int | None  # the inputs' number for this wait (``pending_reset_wait``): repeated while it waits
    began: float  # time.monotonic() at the first announcement

    def payload(self, namespace: str, job_uid: str, now: float) -> bytes:
        """``elapsed`` lets a page that first hears a repeat count the timeout from when the wait began."""
        return json.dumps({"namespace": namespace, "job": job_uid, "at": self.at, "request": self.request,
                           "elapsed": round(max(0.0, now - self.began), 3)}).encode()


def parse_input(model: type[_Input], data: bytes) -> _Input:
    """The checked message, or ``ValueError`` saying what is wrong (never echoing much of it)."""
    if len(data) > MAX_INPUT_BYTES:
        raise ValueError(f"{len(data)} bytes, over the {MAX_INPUT_BYTES}-byte limit")
    try:
        record = json.loads(data)
    except (UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"not JSON ({exc.__class__.__name__})") from None
    if not isinstance(record, dict):
        raise ValueError("not a JSON object")
    try:
        return model.model_validate(record)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or '-'}: {e['msg']}" for e in exc.errors()[:3])
        raise ValueError(problems[:300]) from None


class OperatorInputsBridge:
    """Subscribes one job's teleop subjects and its cell's FMS subjects while the job runs."""

    def __init__(self, link: NatsLink, inputs: OperatorInputs | SidecarInputs, *, namespace: str, job_uid: str,
                 cell: str, announce_resets: bool = True,
                 active_rollout: Callable[[], int | None] | None = None,
                 on_verdict: Callable[[bool, str, int | None], None] | None = None,
                 accepts_verdict: Callable[[int | None], bool] | None = None,
                 on_overrule: Callable[[bool, str, int, datetime], bool] | None = None,
                 reannounce_s: float = REANNOUNCE_S) -> None:
        """``active_rollout``: the index of the rollout the job is in now (None between rollouts).

        ``accepts_verdict(rollout)`` is False for a rollout the job began without outcome
        controls: its verdicts are dropped here, whatever the page showed.

        ``on_verdict(success, by, rollout)`` is told each verdict passed to the job (the
        runner records it in ``status.rollouts``).

        ``on_overrule(success, by, rollout, started_at)`` records an operator's overrule of the
        monitor's verdict on that rollout; False when the monitor judged no such rollout.
        Without it, overrules are dropped.
        """
        self.link = link
        self._active_rollout = active_rollout
        self._on_verdict = on_verdict
        self._accepts_verdict = accepts_verdict
        self._on_overrule = on_overrule
        self.inputs = inputs
        self.namespace, self.job_uid = namespace, job_uid
        self.reset_requested_subject = fms_subject(cell, "reset.requested")
        self._announce_resets = announce_resets
        self.accepted = 0
        self.rejected = 0
        self._rejections = RateLimitedLog(log)
        self._routes: dict[str, tuple[type[_Input], Callable[[_Input], object]]] = {
            teleop_subject(namespace, job_uid, "action"): (TeleopAction, self._teleop_action),
            teleop_subject(namespace, job_uid, "event"): (TeleopEvent, self._teleop_event),
            fms_subject(cell, "reset.confirm"): (ResetConfirm, self._reset_confirm),
            fms_subject(cell, "outcome"): (Outcome, self._outcome),
            fms_subject(cell, "overrule"): (Overrule, self._overrule),
            fms_subject(cell, "stop"): (Stop, self._stop),
        }
        self._subscriptions: list[Subscription] = []
        #: The notice of the reset wait announced last (repeated while that wait waits); a
        #: confirmation naming another request is dropped.
        self._reset_notice: _ResetNotice | None = None
        self._notice_lock = threading.Lock()
        self._reannounce_s = reannounce_s
        self._closed = threading.Event()
        self._repeater: threading.Thread | None = None
        #: Notices sent (first announcements and repeats): what a test or an operator reads to see them go out.
        self.reset_notices_sent = 0

    @property
    def _reset_request(self) -> str | None:
        """The request id of the last reset wait announced."""
        notice = self._reset_notice
        return notice.request if notice is not None else None

    @property
    def subjects(self) -> list[str]:
        return list(self._routes)

    def start(self) -> OperatorInputsBridge:
        """Subscribe; with ``announce_resets``, inputs without a reset prompt get one.

        Inputs that say when a reset waits (``on_reset_requested``): a ``LocalOperatorInputs``
        in this process, or a pod job's ``SidecarInputs`` (``node.sidecar_inputs``).
        """
        self._subscriptions = [self.link.subscribe(subject, self._on_message) for subject in self._routes]
        if (self._announce_resets and isinstance(self.inputs, LocalOperatorInputs | SidecarInputs)
                and self.inputs.on_reset_requested is None):
            self.inputs.on_reset_requested = self.announce_reset_waiting
            self._repeater = threading.Thread(target=self._repeat_notices, name="armnet-reset-notices", daemon=True)
            self._repeater.start()
        return self

    def announce_reset_waiting(self, inputs: object = None) -> None:
        """Tell the cell's operator that the job's reset waits for a confirmation (core NATS, best effort).

        Repeated every ``reannounce_s`` while this wait lasts (``_repeat_notices``).
        """
        at = micro_time(datetime.now(UTC))
        request = reset_request_id(self.job_uid, at)
        wait = self.inputs.pending_reset_wait() if isinstance(self.inputs, LocalOperatorInputs | SidecarInputs) else None
        notice = _ResetNotice(request=request, at=at, wait=wait, began=time.monotonic())
        with self._notice_lock:  # set and sent in one step: a repeat of the previous wait never follows it
            self._reset_notice = notice
            self._send_notice(notice)

    def _send_notice(self, notice: _ResetNotice) -> None:
        """Under ``_notice_lock`` (``notify`` only queues the message on the link's loop)."""
        self.link.notify(self.reset_requested_subject, notice.payload(self.namespace, self.job_uid, time.monotonic()))
        self.reset_notices_sent += 1
        self.link.input_counts.add(reset_notices=1)

    def _repeat_notices(self) -> None:
        while not self._closed.wait(self._reannounce_s):
            try:
                self.repeat_reset_notice()
            except Exception as exc:  # noqa: BLE001 - the repeats must outlive one failure; the next period tries again
                self._rejections.warning("repeating a reset notice failed: %s: %s", type(exc).__name__, exc)

    def repeat_reset_notice(self) -> None:
        """Send the last notice again while its wait still waits (as the inputs last saw it).

        Checked and sent under one lock with ``announce_reset_waiting``, so a repeat of an
        ended wait can never go out after the next wait's first notice.
        """
        if not isinstance(self.inputs, LocalOperatorInputs | SidecarInputs):
            return
        with self._notice_lock:
            notice = self._reset_notice
            if notice is None:
                return
            if notice.wait is not None and self.inputs.pending_reset_wait() == notice.wait:
                self._send_notice(notice)

    def wait_active(self, timeout_s: float) -> bool:
        """True once every subject is subscribed on the server (for callers that must not miss one)."""
        return all(s.wait_active(timeout_s) for s in self._subscriptions)

    def close(self) -> None:
        self._closed.set()
        if self._repeater is not None:
            self._repeater.join(5.0)
            self._repeater = None
        for subscription in self._subscriptions:
            subscription.close()
        self._subscriptions = []
        if (isinstance(self.inputs, LocalOperatorInputs | SidecarInputs)
                and self.inputs.on_reset_requested == self.announce_reset_waiting):
            self.inputs.on_reset_requested = None

    def _on_message(self, subject: str, data: bytes) -> None:
        route = self._routes.get(subject)
        if route is None:
            return
        model, apply = route
        try:
            message = parse_input(model, data)
        except ValueError as exc:
            self.rejected += 1
            self.link.input_counts.add(rejected=1)
            self._rejections.warning("dropped an operator input on %s: %s", subject, exc)
            return
        try:
            apply(message)
        finally:
            self.link.input_counts.add(accepted=1)
            self.accepted += 1  # counted once applied: a caller waiting on the count sees its effect

    def _teleop_action(self, message: _Input) -> None:
        assert isinstance(message, TeleopAction)
        self.inputs.set_teleop_action(dict(message.action) if message.action is not None else None)

    def _teleop_event(self, message: _Input) -> None:
        assert isinstance(message, TeleopEvent)
        self.inputs.push_teleop_event(message.event)

    def _reset_confirm(self, message: _Input) -> None:
        assert isinstance(message, ResetConfirm)
        confirm = self.inputs.confirm_reset
        if isinstance(message.request, str):
            with self._notice_lock:
                notice = self._reset_notice
            if notice is None or message.request != notice.request:
                # Meant for an earlier wait (it timed out, and this one began before the click arrived).
                log.warning("reset confirmation by %s dropped: it names request %s, not the reset waiting now",
                            message.by, message.request[:128])
                return
            wait = notice.wait
            if wait is not None and isinstance(self.inputs, LocalOperatorInputs | SidecarInputs):
                # That wait only: a next wait that began before its own notice went out is not confirmed.
                inputs = self.inputs
                confirm = lambda: inputs.confirm_reset_wait(wait)  # noqa: E731
        if confirm():
            log.info("reset confirmed by %s", message.by)
        else:
            log.warning("reset confirmation by %s dropped: no reset was waiting for one", message.by)

    def _outcome(self, message: _Input) -> None:
        assert isinstance(message, Outcome)
        if message.rollout is not None and self._active_rollout is not None:
            active = self._active_rollout()
            if active != message.rollout:
                # A late click: that rollout ended; it must not end the next one.
                log.warning("episode outcome by %s dropped: it is for rollout %s, the active rollout is %s",
                            message.by, message.rollout, active)
                return
        if self._accepts_verdict is not None and not self._accepts_verdict(message.rollout):
            log.warning("episode outcome by %s dropped: rollout %s began without outcome controls "
                        "(the job decides its outcome)", message.by, message.rollout)
            return
        if self.inputs.report_outcome(message.success) is False:
            # A pod job's connector checked it again and dropped it (the rollout ended meanwhile): not recorded.
            log.warning("episode outcome by %s dropped by the job's connector", message.by)
            return
        log.info("episode outcome %s reported by %s", "success" if message.success else "failure", message.by)
        if self._on_verdict is not None:
            self._on_verdict(message.success, message.by, message.rollout)

    def _overrule(self, message: _Input) -> None:
        assert isinstance(message, Overrule)
        started_at = parse_time(message.started_at)
        if started_at is None:
            log.warning("overrule by %s dropped: startedAt %r is not a time", message.by, message.started_at[:64])
            return
        verdict = "success" if message.success else "failure"
        if self._on_overrule is None or not self._on_overrule(message.success, message.by, message.rollout,
                                                               started_at):
            log.warning("overrule by %s dropped: the monitor judged no rollout %s begun at %s",
                        message.by, message.rollout, message.started_at)
            return
        log.info("the monitor's verdict on rollout %s overruled by %s: %s", message.rollout, message.by, verdict)

    def _stop(self, message: _Input) -> None:
        assert isinstance(message, Stop)
        log.info("stop requested by %s: %s", message.by, message.reason[:200])
        self.inputs.request_stop()
