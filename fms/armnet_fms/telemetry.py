"""The latest camera frames and the last ~30 s of servo telemetry per cell, as the agents publish them. Pure.

The agents publish on core NATS (``telemetry.<cell>.servos``: JSON;
``telemetry.<cell>.camera.<camera>``: JPEG bytes; ``telemetry.<cell>.monitor``: the
completion monitor's verdict now, JSON; docs/fms.md). Every message
is hostile input until checked here: subjects must name a cell the fleet knows
(``known_cells``: the Cells the FMS reads from Kubernetes) and a camera with
plain tokens, frames must be JPEG under ``MAX_FRAME_BYTES``, servo readings are
re-built from the numbers they hold. Memory stays bounded: at most
``max_cells`` cells (the least recently heard is forgotten first),
``MAX_CAMERAS`` frames per cell (one each: only the latest) and at most
``frame_budget_bytes`` of frames in all (the oldest frame anywhere goes first),
and ``MAX_SAMPLES`` servo readings per cell of at most ``MAX_ARMS`` arms of
``MAX_MOTORS`` motors, none older than ``history_s``. Times are the FMS's own
clock at arrival, so an agent's clock skew moves nothing.

While a job runs, the agent publishes only positions (it reads nothing on the
job's bus): such a reading's load and temperature are None. The page's view
follows the latest reading: what it does not read now (load and temperature
while a job runs, an arm it could not read) is not plotted from older reads
either, so a plot never draws a line the page's text says is not read.
"""

from __future__ import annotations

import json
import math
import re
from collections import OrderedDict, deque
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any

MAX_FRAME_BYTES = 256 * 1024
MAX_SERVOS_BYTES = 64 * 1024
MAX_MONITOR_BYTES = 1024
MONITOR_STALE_S = 5.0
"""A monitor verdict older than this is not shown: the job ended, or its agent stopped publishing."""
MAX_CAMERAS = 8
MAX_ARMS = 4
"""Arms per cell kept in a reading (a bimanual cell has 2)."""
MAX_MOTORS = 16
"""Motors per arm kept in a reading (an SO-101 arm has 6)."""
FRAME_BUDGET_BYTES = 64 * 1024 * 1024
"""All cells' latest frames together; past it the oldest frame is dropped (a 320-wide JPEG is ~10-30 KiB)."""
MAX_SAMPLES = 200
"""Servo readings kept per cell: 30 s at the agent's default 4 Hz is 120."""
HISTORY_S = 30.0
MAX_CELLS = 256
JPEG_MAGIC = b"\xff\xd8\xff"
FIELDS = ("position", "load", "temperature")
JOB_UNREAD = ("load", "temperature")
"""What a job's readings never give: the agent puts no traffic of its own on a job's bus."""
_TOKEN = re.compile(r"^[A-Za-z0-9_-]{1,63}$")
_LIMIT = 1 << 20  # no real servo value comes near; anything past it is not a reading


@dataclass(frozen=True)
class Frame:
    jpeg: bytes
    at: float


@dataclass(frozen=True)
class ServoReading:
    """One read of a cell's servos: (arm, motor) -> (position, load, temperature) or None (silent).

    Load and temperature are None when unknown (a job's reads give positions only).
    """

    at: float
    source: str
    motors: tuple[tuple[str, str, tuple[int, int | None, int | None] | None], ...]
    errors: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class MonitorReading:
    """The completion monitor's verdict as an agent last published it (``at``: the FMS's clock at arrival)."""

    at: float
    complete: bool
    score: float


@dataclass
class CellTelemetry:
    frames: dict[str, Frame] = field(default_factory=dict)
    readings: deque[ServoReading] = field(default_factory=lambda: deque(maxlen=MAX_SAMPLES))
    monitor: MonitorReading | None = None
    heard_at: float = 0.0


def parse_subject(subject: str) -> tuple[str, str | None] | None:
    """(cell, camera) for ``telemetry.<cell>.camera.<camera>``, (cell, None) for ``.servos``; else None."""
    parts = subject.split(".")
    if len(parts) == 3 and parts[0] == "telemetry" and parts[2] == "servos" and _TOKEN.match(parts[1]):
        return parts[1], None
    if (len(parts) == 4 and parts[0] == "telemetry" and parts[2] == "camera"
            and _TOKEN.match(parts[1]) and _TOKEN.match(parts[3])):
        return parts[1], parts[3]
    return None


def parse_monitor_subject(subject: str) -> str | None:
    """The cell of ``telemetry.<cell>.monitor``; else None."""
    parts = subject.split(".")
    if len(parts) == 3 and parts[0] == "telemetry" and parts[2] == "monitor" and _TOKEN.match(parts[1]):
        return parts[1]
    return None


def _json_object(data: bytes, cap: int) -> dict[str, Any] | None:
    """``data`` as a JSON object when it is one of at most ``cap`` bytes, else None."""
    if len(data) > cap:
        return None
    try:
        body = json.loads(data)
    except ValueError:
        return None
    return body if isinstance(body, dict) else None


def parse_monitor(data: bytes, at: float) -> MonitorReading | None:
    """The verdict in an agent's ``monitor`` message, or None when it is not one (a score is within 0..1)."""
    body = _json_object(data, MAX_MONITOR_BYTES)
    if body is None or not isinstance(body.get("complete"), bool):
        return None
    score = body.get("score")
    if isinstance(score, bool) or not isinstance(score, int | float) or not 0.0 <= score <= 1.0:
        return None
    return MonitorReading(at, body["complete"], float(score))


def _number(value: Any) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    if isinstance(value, float) and not math.isfinite(value):
        return None
    number = int(value)
    return number if -_LIMIT < number < _LIMIT else None


def _sample(sample: Any) -> tuple[int, int | None, int | None] | None:
    """(position, load, temperature) of one motor's entry; None when it has no position (silent)."""
    if not isinstance(sample, dict):
        return None
    position, load, temperature = (_number(sample.get(f)) for f in FIELDS)
    return None if position is None else (position, load, temperature)


def parse_servos(data: bytes, at: float) -> ServoReading | None:
    """The reading in an agent's ``servos`` message, or None when it is not one."""
    body = _json_object(data, MAX_SERVOS_BYTES)
    if body is None or not isinstance(body.get("arms"), dict):
        return None
    source = body.get("source")
    motors: list[tuple[str, str, tuple[int, int | None, int | None] | None]] = []
    errors: list[tuple[str, str]] = []
    for arm, entry in list(body["arms"].items())[:MAX_ARMS]:
        if not isinstance(entry, dict) or not _TOKEN.match(str(arm)):
            continue
        if isinstance(entry.get("error"), str):
            errors.append((arm, entry["error"][:200]))
            continue
        table = entry.get("motors")
        if not isinstance(table, dict):
            continue
        for motor, sample in list(table.items())[:MAX_MOTORS]:
            if not _TOKEN.match(str(motor)):
                continue
            motors.append((arm, motor, _sample(sample)))
    return ServoReading(at, source if source in ("idle", "job") else "unknown", tuple(motors), tuple(errors))


class TelemetryStore:
    """What the page shows of each cell's cameras and servos; ``accept`` every NATS message."""

    def __init__(self, *, history_s: float = HISTORY_S, max_cells: int = MAX_CELLS,
                 frame_budget_bytes: int = FRAME_BUDGET_BYTES,
                 known_cells: Callable[[], Collection[str]] | None = None) -> None:
        """``known_cells``: the cells whose telemetry is kept (None: any, for a local run's own cell)."""
        self.history_s = history_s
        self.max_cells = max_cells
        self.frame_budget_bytes = frame_budget_bytes
        self._known_cells = known_cells
        self._cells: OrderedDict[str, CellTelemetry] = OrderedDict()
        self._frame_bytes = 0
        #: Messages kept and refused (bad subject, unknown cell, not JPEG, too large, not a reading),
        #: and dropped by the NATS client before they reached the store (the FMS fell behind).
        self.kept = 0
        self.refused = 0
        self.dropped = 0

    def count_dropped(self, count: int = 1) -> None:
        """Messages NATS dropped for this subscriber (its pending limit was reached)."""
        self.dropped += count

    def accept(self, subject: str, data: bytes, now: float) -> bool:
        """Keep the message if it is a valid frame or reading of a known cell; False (and counted) when refused."""
        target = parse_subject(subject)
        monitored = parse_monitor_subject(subject)
        if self._known_cells is not None:  # not a cell of the fleet: anyone on NATS could name thousands
            known = self._known_cells()
            target = target if target is not None and target[0] in known else None
            monitored = monitored if monitored in known else None
        kept = False
        if monitored is not None:
            verdict = parse_monitor(data, now)
            if verdict is not None:
                self._entry(monitored, now).monitor = verdict
                kept = True
        elif target is not None:
            cell, camera = target
            if camera is not None:
                kept = self._keep_frame(cell, camera, data, now)
            else:
                reading = parse_servos(data, now)
                if reading is not None:
                    entry = self._entry(cell, now)
                    entry.readings.append(reading)
                    self._trim(entry, now)
                    kept = True
        if kept:
            self.kept += 1
        else:
            self.refused += 1
        return kept

    def _keep_frame(self, cell: str, camera: str, data: bytes, now: float) -> bool:
        if len(data) > MAX_FRAME_BYTES or not data.startswith(JPEG_MAGIC):
            return False
        entry = self._cells.get(cell)
        if entry is not None and camera not in entry.frames and len(entry.frames) >= MAX_CAMERAS:
            return False
        frames = self._entry(cell, now).frames
        old = frames.get(camera)
        frames[camera] = Frame(bytes(data), now)
        self._frame_bytes += len(data) - (len(old.jpeg) if old is not None else 0)
        while self._frame_bytes > self.frame_budget_bytes:
            self._drop_oldest_frame()
        return True

    def _drop_oldest_frame(self) -> None:
        cell, camera = min(((c, name) for c, e in self._cells.items() for name in e.frames),
                           key=lambda key: self._cells[key[0]].frames[key[1]].at)
        self._frame_bytes -= len(self._cells[cell].frames.pop(camera).jpeg)

    @property
    def frame_bytes(self) -> int:
        """Bytes of all frames held."""
        return self._frame_bytes

    def _entry(self, cell: str, now: float) -> CellTelemetry:
        entry = self._cells.get(cell)
        if entry is None:
            while len(self._cells) >= self.max_cells:
                _, gone = self._cells.popitem(last=False)  # the least recently heard cell
                self._frame_bytes -= sum(len(frame.jpeg) for frame in gone.frames.values())
            entry = self._cells[cell] = CellTelemetry()
        self._cells.move_to_end(cell)
        entry.heard_at = now
        return entry

    def _trim(self, entry: CellTelemetry, now: float) -> None:
        while entry.readings and entry.readings[0].at < now - self.history_s:
            entry.readings.popleft()

    def frame(self, cell: str, camera: str) -> Frame | None:
        entry = self._cells.get(cell)
        return entry.frames.get(camera) if entry is not None else None

    @property
    def frames_held(self) -> int:
        return sum(len(entry.frames) for entry in self._cells.values())

    def view(self, cell: str, now: float) -> dict[str, Any]:
        """The page's telemetry of ``cell``: cameras with their frame age, each motor's series, and the
        completion monitor's verdict now (``monitor``: complete, score, ``ageS``; null without a fresh one).

        ``series`` is ``[{"arm", "motor", "points": [[age_s, position, load, temperature], ...]}]``,
        oldest first, ``age_s`` in seconds before ``now`` (a silent motor has no point at that read).
        ``unread``: the quantities the latest reading does not read (a job's reads give positions
        only); they are null at every point, older reads included. An arm the latest reading names
        in ``errors`` has no series: its older points would draw a line the page says is not read.
        """
        entry = self._cells.get(cell)
        if entry is None:
            return {"cell": cell, "cameras": [], "series": [], "source": None, "ageS": None, "unread": [],
                    "errors": [], "monitor": None}
        readings = [r for r in entry.readings if r.at >= now - self.history_s]
        last = readings[-1] if readings else None
        unread = unread_fields(last)
        keep = [name not in unread for name in FIELDS]
        unread_arms = {arm for arm, _ in last.errors} if last is not None else set()
        series: dict[tuple[str, str], list[list[float | None]]] = {}
        for reading in readings:
            age = round(now - reading.at, 2)
            for arm, motor, values in reading.motors:
                if arm in unread_arms:
                    continue
                points = series.setdefault((arm, motor), [])
                if values is not None:
                    points.append([age, *(v if k else None for v, k in zip(values, keep, strict=True))])
        return {
            "cell": cell,
            "cameras": [{"name": name, "ageS": round(now - frame.at, 2)} for name, frame in sorted(entry.frames.items())],
            "series": [{"arm": arm, "motor": motor, "points": points} for (arm, motor), points in series.items()],
            "source": last.source if last is not None else None,
            "ageS": round(now - last.at, 2) if last is not None else None,
            "unread": list(unread),
            "errors": [{"arm": arm, "error": error} for arm, error in (last.errors if last is not None else ())],
            "monitor": _monitor_view(entry.monitor, now),
        }


def _monitor_view(monitor: MonitorReading | None, now: float) -> dict[str, Any] | None:
    """The monitor's verdict for the page (``ageS``: since it arrived); None when none came in ``MONITOR_STALE_S``."""
    if monitor is None or now - monitor.at > MONITOR_STALE_S:
        return None
    return {"complete": monitor.complete, "score": round(monitor.score, 3), "ageS": round(now - monitor.at, 2)}


def unread_fields(last: ServoReading | None) -> tuple[str, ...]:
    """The quantities the latest reading does not read (the page says so and plots none of their values)."""
    return JOB_UNREAD if last is not None and last.source == "job" else ()
