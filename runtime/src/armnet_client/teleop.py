"""Teleoperation, pure part: subjects, payloads, the keys' recording events, a simulated leader arm.

The client samples a leader arm and publishes its action on
``teleop.<namespace>.<jobId>.action`` as ``{"action": {motor: value}}``; the
cell keeps only the latest, so the client publishes plain NATS (no JetStream:
an old action replayed later would be wrong, not late). Keys publish
``{"event": ...}`` on ``teleop.<namespace>.<jobId>.event`` with LeRobot's
recording shortcuts: Right arrow ``next_episode``, Left arrow
``rerecord_episode``, Esc ``stop_recording`` (docs/streams.md).
"""

from __future__ import annotations

import json
import math
from typing import Optional

from .logwire import job_subjects

NEXT_EPISODE = "next_episode"
RERECORD_EPISODE = "rerecord_episode"
STOP_RECORDING = "stop_recording"

_RIGHT = b"\x1b[C"
_LEFT = b"\x1b[D"
_ESC = b"\x1b"

SO101_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")


def teleop_subject(namespace: str, job_id: str, kind: str) -> str:
    """``teleop.<ns>.<jobId>.<kind>``; the tokens are checked as for the log subjects."""
    if kind not in ("action", "event"):
        raise ValueError(f"teleop subject kind must be action or event, not {kind!r}")
    job_subjects(namespace, job_id)
    return f"teleop.{namespace}.{job_id}.{kind}"


def action_payload(action: dict[str, float]) -> bytes:
    return json.dumps({"action": {str(k): float(v) for k, v in action.items()}},
                      separators=(",", ":")).encode()


def event_payload(event: str) -> bytes:
    return json.dumps({"event": event}).encode()


def events_of_keys(chunk: bytes) -> list[str]:
    """The recording events in one read from a raw-mode terminal.

    A terminal sends an arrow as one ``ESC [ C|D`` sequence in one read, and the
    Esc key as a lone ``ESC``; other keys are ignored.
    """
    events: list[str] = []
    rest = chunk
    while rest:
        if rest.startswith(_RIGHT):
            events.append(NEXT_EPISODE)
            rest = rest[len(_RIGHT):]
        elif rest.startswith(_LEFT):
            events.append(RERECORD_EPISODE)
            rest = rest[len(_LEFT):]
        elif rest.startswith(b"\x1b[") and len(rest) >= 3:
            rest = rest[3:]  # another arrow or a function key: not a recording shortcut
        elif rest.startswith(_ESC) and (len(rest) == 1 or rest[1:2] != b"["):
            events.append(STOP_RECORDING)
            rest = rest[1:]
        else:
            rest = rest[1:]
    return events


def simulated_action(t: float, *, amplitude_deg: float = 10.0, period_s: float = 8.0) -> dict[str, float]:
    """A simulated SO-101 leader at time ``t``: slow sines, phase-shifted per joint, keys as LeRobot's.

    Small and smooth on purpose: consecutive samples differ by far less than any
    cell's safety limit, so a follower tracks it without tripping the interlock.
    """
    phase = 2 * math.pi * t / period_s
    action = {f"{joint}.pos": round(amplitude_deg * math.sin(phase + i * 0.7), 3)
              for i, joint in enumerate(SO101_JOINTS)}
    action["gripper.pos"] = round(50.0 + 20.0 * math.sin(phase), 3)
    return action


def leader_label(leader: str) -> str:
    return "simulated leader" if leader == "sim" else f"leader arm on {leader}"


def stop_requested(events: list[str]) -> Optional[str]:
    return STOP_RECORDING if STOP_RECORDING in events else None
