"""Operator inputs: teleop, outcomes, stop requests and reset confirmations.

This module owns the small interface between the humans at a cell and the
connector's ``operator.sock``, with an in-memory implementation that local mode
feeds from a JSON-lines file or stdin; the node agent's NATS bridge
(``armnet_node.inputs_bridge``) feeds the same interface.
It never touches hardware.
"""

from __future__ import annotations

import json
import logging
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

log = logging.getLogger(__name__)


class OperatorInputs(Protocol):
    """What the connector reads from the operator side. Producers call the setters."""

    def set_teleop_action(self, action: dict[str, Any] | None) -> None: ...
    def push_teleop_event(self, event: str) -> None: ...
    def report_outcome(self, success: bool) -> None: ...
    def request_stop(self) -> None: ...
    def confirm_reset(self) -> bool: ...

    def pending_reset_wait(self) -> int | None: ...
    def confirm_reset_wait(self, number: int) -> bool: ...
    def latest_teleop_action(self) -> dict[str, Any] | None: ...
    def next_teleop_event(self) -> str | None: ...
    def take_outcome(self) -> bool | None: ...
    def stop_requested(self) -> bool: ...
    def wait_reset_confirmation(self, timeout_s: float) -> bool: ...
    def wait_reset_pending(self, timeout_s: float | None) -> bool: ...


@dataclass(frozen=True)
class MonitorVerdict:
    """What an automated monitor says now, for the record (``status.rollouts``): auditable later."""

    complete: bool
    #: The scorer's score of the frames the verdict rests on (the lowest of the streak).
    score: float
    #: Wall-clock time the newest of those frames was scored (None before any frame was).
    frame_at: float | None


@dataclass(frozen=True)
class SceneJudgement:
    """The monitor's judgement of a scripted reset: is the scene back at its start (nothing in the region)?"""

    #: ``frames`` fresh frames were scored and none was a hit.
    reset: bool
    #: Frames captured after the judgement began that were scored (a scorer failure is not a score).
    scored: int
    #: How many of them were hits (the task's object still in its target region).
    hits: int
    #: The latest scored frame's detail, or why too few were scored.
    detail: str


class CompletionMonitor(Protocol):
    """The cell's automated episode scoring (``is_complete`` on robot.sock)."""

    def is_complete(self, *, block: bool) -> tuple[bool, bool]: ...

    def audit(self) -> MonitorVerdict | None:
        """The verdict to record on the rollout; None for a cell that scores nothing."""
        ...

    def judge_reset(self, frames: int, timeout_s: float) -> SceneJudgement | None:
        """Wait for ``frames`` frames captured after the call to be scored (at most ``timeout_s``) and judge
        whether the scene is back at its start; None for a cell that scores nothing."""
        ...


class NeverComplete:
    """Default monitor: a cell without automated scoring never declares an episode complete.

    Human outcomes reach the job through ``get_completion`` on operator.sock, which the
    SDK consults before it asks ``is_complete``.
    """

    def is_complete(self, *, block: bool) -> tuple[bool, bool]:
        return False, False

    def audit(self) -> MonitorVerdict | None:
        return None

    def judge_reset(self, frames: int, timeout_s: float) -> SceneJudgement | None:
        return None


class LocalOperatorInputs:
    """Thread-safe in-memory operator inputs.

    ``auto_confirm_reset`` confirms every reset at once (scripted runs);
    ``on_reset_requested`` is called when a reset starts to wait (a terminal
    prompt, a notification), and may call ``confirm_reset`` from any thread.

    A confirmation reaches only the reset waiting when it arrives: one given
    while no reset waits (a double click, a late message, one meant for the
    previous episode) is dropped, logged and counted in
    ``ignored_confirmations``, so it can never confirm a later reset whose
    workspace nobody has reset. A reset waits once the arm is at its rest pose,
    which is when a person may safely reach into the workspace.
    """

    def __init__(
        self,
        *,
        auto_confirm_reset: bool = False,
        on_reset_requested: Callable[[LocalOperatorInputs], None] | None = None,
    ) -> None:
        self.auto_confirm_reset = auto_confirm_reset
        self.on_reset_requested = on_reset_requested
        self._cond = threading.Condition()
        self._action: dict[str, Any] | None = None
        self._events: deque[str] = deque()
        self._outcome: bool | None = None
        self._stop = False
        self._waiting = 0  # resets waiting for a confirmation (the connector runs one at a time)
        self._confirmations = 0  # confirmations given to those resets, not yet taken
        self._wait_number = 0  # each reset wait numbered from 1, when it begins (a pod's agent names the one it confirms)
        self.ignored_confirmations = 0

    def set_teleop_action(self, action: dict[str, Any] | None) -> None:
        with self._cond:
            self._action = action

    def push_teleop_event(self, event: str) -> None:
        with self._cond:
            self._events.append(event)

    def report_outcome(self, success: bool) -> None:
        with self._cond:
            self._outcome = bool(success)

    def request_stop(self) -> None:
        with self._cond:
            self._stop = True

    def confirm_reset(self) -> bool:
        """Confirm the waiting reset; False (dropped and logged) when no reset waits for one."""
        with self._cond:
            if self._confirmations >= self._waiting:
                self.ignored_confirmations += 1
                dropped = True
            else:
                self._confirmations += 1
                self._cond.notify_all()
                dropped = False
        if dropped:
            log.warning("ignored a reset confirmation: no reset is waiting for one")
        return not dropped

    def pending_reset_wait(self) -> int | None:
        """The number of the reset wait that waits for a confirmation now, else None.

        Read together with the wait's state (one lock), so a number is never that of
        an earlier wait while a new one already waits.
        """
        with self._cond:
            return self._wait_number if self._waiting > self._confirmations else None

    def confirm_reset_wait(self, number: int) -> bool:
        """Confirm reset wait ``number`` only if it is the one waiting now; else dropped (False), as ``confirm_reset``."""
        with self._cond:
            dropped = number != self._wait_number or self._confirmations >= self._waiting
            if dropped:
                self.ignored_confirmations += 1
            else:
                self._confirmations += 1
                self._cond.notify_all()
        if dropped:
            log.warning("ignored a reset confirmation for reset wait %d: it is not the reset waiting now", number)
        return not dropped

    def latest_teleop_action(self) -> dict[str, Any] | None:
        with self._cond:
            return self._action

    def next_teleop_event(self) -> str | None:
        with self._cond:
            return self._events.popleft() if self._events else None

    def take_outcome(self) -> bool | None:
        with self._cond:
            outcome, self._outcome = self._outcome, None
            return outcome

    def stop_requested(self) -> bool:
        with self._cond:
            return self._stop

    def wait_reset_confirmation(self, timeout_s: float) -> bool:
        if self.auto_confirm_reset:
            return True
        with self._cond:
            self._waiting += 1
            self._wait_number += 1
            self._cond.notify_all()
        try:
            if self.on_reset_requested is not None:
                self.on_reset_requested(self)
            with self._cond:
                if not self._cond.wait_for(lambda: self._confirmations > 0, timeout=timeout_s):
                    return False
                self._confirmations -= 1
                return True
        finally:
            with self._cond:
                self._waiting -= 1
                self._confirmations = min(self._confirmations, self._waiting)

    def wait_reset_pending(self, timeout_s: float | None) -> bool:
        """Wait until a reset waits for a confirmation it has not yet got (None: no time limit)."""
        with self._cond:
            return self._cond.wait_for(lambda: self._waiting > self._confirmations, timeout=timeout_s)


def apply_input_line(inputs: OperatorInputs, line: str) -> None:
    """Apply one JSON-lines input record; raise ``ValueError`` saying what is accepted.

    Records: ``{"teleop_action": {...}|null}``, ``{"teleop_event": "next_episode"}``,
    ``{"outcome": true|false}``, ``{"stop": true}``, ``{"confirm_reset": true}``.
    """
    record = json.loads(line)
    if not isinstance(record, dict) or len(record) != 1:
        raise ValueError(f"an input line is one JSON object with one key, got {line.strip()[:80]!r}")
    (key, value), = record.items()
    if key == "teleop_action" and (value is None or isinstance(value, dict)):
        inputs.set_teleop_action(value)
    elif key == "teleop_event" and isinstance(value, str):
        inputs.push_teleop_event(value)
    elif key == "outcome" and isinstance(value, bool):
        inputs.report_outcome(value)
    elif key == "stop" and value is True:
        inputs.request_stop()
    elif key == "confirm_reset" and value is True:
        inputs.confirm_reset()
    else:
        raise ValueError(
            f"unknown input {line.strip()[:80]!r}; accepted keys: teleop_action (object|null), "
            "teleop_event (string), outcome (bool), stop (true), confirm_reset (true)"
        )


def feed_lines(inputs: OperatorInputs, lines: Iterable[str]) -> None:
    """Apply every line in order (blank lines skipped; bad lines logged and skipped).

    A script's ``confirm_reset`` line is the confirmation of the next reset: the
    feed waits at it until a reset waits, so the lines after it apply after that
    reset, as written.
    """
    for line in lines:
        if not line.strip():
            continue
        try:
            if _is_reset_confirmation(line):
                inputs.wait_reset_pending(None)
            apply_input_line(inputs, line)
        except ValueError as exc:  # json.JSONDecodeError is a ValueError
            log.warning("ignored operator input: %s", exc)


def _is_reset_confirmation(line: str) -> bool:
    record = json.loads(line)
    return isinstance(record, dict) and record == {"confirm_reset": True}


@dataclass
class InputFeeder:
    """A daemon thread feeding ``inputs`` from a JSON-lines file path or ``-`` (stdin)."""

    inputs: OperatorInputs
    source: str
    _thread: threading.Thread | None = field(default=None, init=False)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="armnet-inputs", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        if self.source == "-":
            feed_lines(self.inputs, sys.stdin)
            return
        with open(self.source, encoding="utf-8") as stream:
            feed_lines(self.inputs, stream)


def terminal_prompt(inputs: LocalOperatorInputs) -> None:
    """``on_reset_requested`` for a person at the terminal: confirm with Enter on /dev/tty."""

    def wait_for_enter() -> None:
        try:
            with open("/dev/tty", encoding="utf-8") as tty:
                print("armnet: reset the cell workspace, then press Enter to confirm.", file=sys.stderr)
                tty.readline()
        except OSError as exc:
            log.warning("cannot prompt for a reset confirmation on the terminal: %s", exc)
            return
        inputs.confirm_reset()

    threading.Thread(target=wait_for_enter, name="armnet-reset-prompt", daemon=True).start()
