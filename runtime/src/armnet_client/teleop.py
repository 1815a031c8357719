"""Teleoperation, pure part: subjects, payloads, the keys' recording events, a simulated leader arm.

The client samples a leader arm and publishes its action on
``teleop.<namespace>.<jobId>.action`` as ``{"action": {motor: value}}``; the
cell keeps only the latest, so the client publishes plain NATS (no JetStream:
an old action replayed later would be wrong, not late). Keys publish
``{"event": ...}`` on ``teleop.<namespace>.<jobId>.event`` with LeRobot's
recording shortcuts: Right arrow ``next_episode``, Left arrow
``rerecord_episode``, Esc ``stop_recording`` (docs/streams.md).

The follower's state comes back the way the job reports it: the observation
scalars of its ``ctx.log_rerun_data(observation=...)`` packets on
``logs.<namespace>.<jobId>.rerun`` (the same packets ``armnet view`` shows).
The client never asks the cell: the job, not the client, decides what to report.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Optional

from armnet_runtime.rerun import Packet

from .logwire import job_subjects

NEXT_EPISODE = "next_episode"
RERECORD_EPISODE = "rerecord_episode"
STOP_RECORDING = "stop_recording"

_OBSERVATION = "observation."
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


def rerun_subject(namespace: str, job_id: str) -> str:
    """``logs.<ns>.<jobId>.rerun``: where the job's Rerun packets (and so the follower's state) arrive."""
    return job_subjects(namespace, job_id)[:-1] + "rerun"


def follower_state(packet: Packet) -> Optional[dict[str, float]]:
    """The observation scalars of one packet, keyed as the job's observation (``shoulder_pan.pos``).

    ``None`` for a packet without observation scalars (an action-only or
    image-only frame), so the last known state stays on screen.
    """
    state = {entry.path[len(_OBSERVATION):]: entry.scalar for entry in packet.entries
             if entry.scalar is not None and entry.path.startswith(_OBSERVATION)}
    return state or None


@dataclass(frozen=True)
class FollowerView:
    """The follower's last reported state and how long ago it arrived (``None``: nothing yet)."""

    state: Optional[dict[str, float]] = None
    age_s: float = 0.0


def status_lines(leader: str, actions: int, last_event: Optional[str], follower: FollowerView) -> list[str]:
    """The two live lines ``armnet teleop`` keeps redrawn: what was sent, and the follower's state."""
    sent = f"{leader_label(leader)}: {actions} actions sent, last event {last_event or '-'}"
    if follower.state is None:
        return [sent, "follower: no state yet (the job reports it with ctx.log_rerun_data(observation=...))"]
    joints = "  ".join(f"{printable(name.removesuffix('.pos'))} {value:.1f}" for name, value in follower.state.items())
    return [sent, f"follower ({follower.age_s:.1f} s ago): {joints}"]


def printable(name: str, limit: int = 64) -> str:
    """A job-chosen name as it may reach the terminal: printable ASCII only, at most ``limit`` characters.

    The names come from the job's packets: control characters would be terminal
    escapes (cursor moves, title changes), and wide characters would break the
    redraw's column arithmetic.
    """
    return "".join(c if " " <= c <= "~" else "?" for c in name[:limit])


def redraw(lines: list[str], drawn_before: int, width: int) -> str:
    """Terminal output that replaces the ``drawn_before`` lines last drawn with ``lines``.

    Each line is cut to ``width`` so none wraps (a wrapped line would break the
    cursor arithmetic); the cursor ends at the end of the last line.
    """
    up = f"\x1b[{drawn_before - 1}A" if drawn_before > 1 else ""
    cut = max(width - 1, 1)
    return up + "\r" + "\n".join("\x1b[2K" + line[:cut] for line in lines)
