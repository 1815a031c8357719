"""What the agent publishes for the cell operator's page, and when. Pure.

Subjects (core NATS, not stored: a page wants the present, not a replay):

- ``telemetry.<cell>.servos``: one JSON object per read (``servos_payload``),
  a few times a second;
- ``telemetry.<cell>.camera.<camera>``: the camera's latest frame as JPEG bytes,
  about twice a second, scaled to at most ``MAX_FRAME_WIDTH`` pixels wide.
- ``telemetry.<cell>.monitor``: the completion monitor's verdict now (``monitor_payload``),
  with each servo reading while a job runs on a cell with a monitor.

Every size is bounded here, so a cell with hostile names or many motors cannot
make a message the FMS has to hold large.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol

SUBJECT_PREFIX = "telemetry"
MAX_FRAME_WIDTH = 320
"""Frames are scaled down to this width: enough to see the workspace on a tablet, ~10-30 KiB as JPEG."""
JPEG_QUALITY = 70
MAX_FRAME_BYTES = 256 * 1024
"""A JPEG over this is not published (counted as failed): the FMS holds one per camera."""
MAX_ARMS = 4
MAX_MOTORS = 16
MAX_CAMERAS = 8
MAX_TEXT = 200
_TOKEN = re.compile(r"^[A-Za-z0-9_-]{1,63}$")


class ServoSample(Protocol):
    """One servo's readings (``connector.telemetry.ServoSample``)."""

    @property
    def position(self) -> int: ...
    @property
    def load(self) -> int | None: ...
    @property
    def temperature(self) -> int | None: ...


def subject_token(value: str, what: str) -> str:
    """``value`` when it is a safe NATS subject token (no dots, wildcards or spaces), else ValueError."""
    if not _TOKEN.match(value):
        raise ValueError(f"{what} {value[:64]!r} cannot be a NATS subject token (use letters, digits, '-' or '_')")
    return value


def servos_subject(cell: str) -> str:
    return f"{SUBJECT_PREFIX}.{subject_token(cell, 'cell')}.servos"


def camera_subject(cell: str, camera: str) -> str:
    return f"{SUBJECT_PREFIX}.{subject_token(cell, 'cell')}.camera.{subject_token(camera, 'camera')}"


def monitor_subject(cell: str) -> str:
    return f"{SUBJECT_PREFIX}.{subject_token(cell, 'cell')}.monitor"


def monitor_payload(at: float, complete: bool, score: float, frame_at: float | None) -> bytes:
    """The monitor's verdict as JSON: ``{"t", "complete", "score", "frameAt"}`` (``frameAt``: when the newest
    frame it rests on was scored, wall clock; null before the first)."""
    body = {"t": round(at, 3), "complete": complete, "score": round(score, 4),
            "frameAt": None if frame_at is None else round(frame_at, 3)}
    return json.dumps(body, separators=(",", ":")).encode()


def servos_payload(
    at: float,
    source: str,
    arms: Mapping[str, Mapping[str, ServoSample | None] | str],
) -> bytes:
    """One read as JSON: ``{"t", "source", "arms": {arm: {"motors": {motor: {...} | null}} | {"error"}}}``.

    ``source`` says who read the servos: ``idle`` (the agent, no job) or ``job``
    (the job's own reads, as its connector recorded them). A motor that did not
    answer is ``null``; ``load`` and ``temperature`` are left out when unknown
    (a job's reads give positions only).
    """
    body: dict[str, Any] = {}
    for arm, reading in list(sorted(arms.items()))[:MAX_ARMS]:
        if isinstance(reading, str):
            body[arm[:64]] = {"error": reading[:MAX_TEXT]}
            continue
        motors = {motor[:64]: _sample(sample) for motor, sample in list(sorted(reading.items()))[:MAX_MOTORS]}
        body[arm[:64]] = {"motors": motors}
    return json.dumps({"t": round(at, 3), "source": source[:16], "arms": body}, separators=(",", ":")).encode()


def _sample(sample: ServoSample | None) -> dict[str, int] | None:
    if sample is None:
        return None
    values = {"position": sample.position, "load": sample.load, "temperature": sample.temperature}
    return {key: value for key, value in values.items() if value is not None}


def scaled_size(width: int, height: int, max_width: int = MAX_FRAME_WIDTH) -> tuple[int, int]:
    """The size a frame is published at: at most ``max_width`` wide, same aspect, never enlarged."""
    if width <= 0 or height <= 0:
        raise ValueError(f"a frame has a positive size, got {width}x{height}")
    if width <= max_width:
        return width, height
    return max_width, max(1, round(height * max_width / width))


@dataclass(frozen=True)
class Cadence:
    """When a periodic action is next due: at most once per ``period_s``, never in bursts after a stall.

    ``period_s`` of 0 (or less) turns the action off. A value: ``due`` returns the
    cadence to keep using.
    """

    period_s: float
    next_at: float = 0.0

    @classmethod
    def per_second(cls, rate: float) -> Cadence:
        return cls(1.0 / rate if rate > 0 else 0.0)

    @property
    def enabled(self) -> bool:
        return self.period_s > 0

    def due(self, now: float) -> tuple[bool, Cadence]:
        """(whether the action runs at ``now``, the cadence after it)."""
        if not self.enabled or now < self.next_at:
            return False, self
        late = now - self.next_at
        # On time: keep the grid. Late by more than a period (a slow read, a busy host): restart from now.
        next_at = (self.next_at + self.period_s) if late < self.period_s else now + self.period_s
        return True, replace(self, next_at=next_at)

    def wait_s(self, now: float) -> float:
        """Seconds until the next run (0 when due)."""
        return max(0.0, self.next_at - now)
