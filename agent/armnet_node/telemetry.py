"""Publishes a cell's servo telemetry and camera frames on NATS for the cell operator's page.

One thread per cell worker, only when the agent has a NATS link. Each tick asks
the worker for the cell's current source of readings:

- idle (no job): the agent reads the servos itself, with the same turn-taking as
  the health probe (``BusTurns``: never beside a launch), and draws a simulated
  cell's cameras from its simulator;
- a job runs with the connector in this process: the connector's cell
  (``connector.telemetry.job_servos``: the positions the job's own reads left
  in the connector, no traffic on the job's bus, so no load or temperature;
  frames are the job's cameras' latest captures);
- a job runs in a pod: the same, through the sidecar's observer socket.

With each servo reading of a job on a cell with a completion monitor, the monitor's
verdict now (``telemetry.<cell>.monitor``): the page shows it live while a rollout runs.

Everything is best effort: a failing camera or read is counted and logged at
most once a minute, and never stops the other readings nor the job.

``stop`` only asks the thread to end (the worker's reconcile pass never waits
on a camera); the thread itself runs ``on_exit`` (closing the agent's idle
cameras and arm handles) as it leaves, so nothing closes a camera under a read.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

from armnet_connector.inputs import MonitorVerdict
from armnet_connector.ratelog import RateLimitedLog
from armnet_connector.telemetry import CameraFrame
from armnet_connector.telemetry_decode import ServoSample

from armnet_node.metrics import AgentMetrics
from armnet_node.telemetry_wire import (
    JPEG_QUALITY,
    MAX_CAMERAS,
    MAX_FRAME_BYTES,
    Cadence,
    camera_subject,
    monitor_payload,
    monitor_subject,
    scaled_size,
    servos_payload,
    servos_subject,
)

log = logging.getLogger(__name__)

ServoReadings = Mapping[str, Mapping[str, ServoSample | None] | str]


class TelemetrySource(Protocol):
    """Where a cell's readings come from right now (idle: the agent; a job: its connector)."""

    name: str

    def servos(self) -> ServoReadings | None:
        """arm -> motor -> sample (or why the arm was not read); None when nothing may be read now."""
        ...

    def frames(self) -> Mapping[str, CameraFrame | str]:
        """camera -> its latest frame, or why there is none."""
        ...

    def monitor(self) -> MonitorVerdict | None:
        """The cell's completion monitor's verdict now; None when no monitor scores (idle, or a cell without one)."""
        ...


class Notifier(Protocol):
    def notify(self, subject: str, payload: bytes) -> None: ...


MAX_SERVO_HZ = 20.0
"""Reads per second an idle arm takes at most: each is bus time a probe or a launch waits for."""
MAX_FRAME_FPS = 10.0
"""Frames per second per camera at most: each is a JPEG every page viewer's FMS relays."""


@dataclass(frozen=True)
class TelemetrySettings:
    servo_hz: float = 4.0
    frame_fps: float = 2.0

    def __post_init__(self) -> None:
        if not 0 <= self.servo_hz <= MAX_SERVO_HZ:
            raise ValueError(f"telemetry servo rate {self.servo_hz:g}/s is outside 0..{MAX_SERVO_HZ:g} "
                             "(0 turns servo telemetry off)")
        if not 0 <= self.frame_fps <= MAX_FRAME_FPS:
            raise ValueError(f"telemetry frame rate {self.frame_fps:g}/s is outside 0..{MAX_FRAME_FPS:g} "
                             "(0 turns camera telemetry off)")

    @property
    def enabled(self) -> bool:
        return self.servo_hz > 0 or self.frame_fps > 0


def encode_jpeg(frame: CameraFrame) -> bytes:
    """The frame scaled to the published width, as JPEG; ValueError when it cannot be or is too large."""
    import cv2
    import numpy as np

    image = np.asarray(frame.image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"a camera frame is HxWx3 uint8, got shape {image.shape} dtype {image.dtype}")
    height, width = image.shape[:2]
    size = scaled_size(width, height)
    if size != (width, height):
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    if not frame.bgr:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("OpenCV could not encode the frame as JPEG")
    payload = bytes(data)
    if len(payload) > MAX_FRAME_BYTES:
        raise ValueError(f"the JPEG is {len(payload)} bytes, over the {MAX_FRAME_BYTES}-byte limit")
    return payload


class CellTelemetry:
    """The publishing thread of one cell; ``source()`` is asked anew every tick."""

    def __init__(
        self,
        cell: str,
        source: Callable[[], TelemetrySource | None],
        link: Notifier,
        metrics: AgentMetrics,
        settings: TelemetrySettings,
        clock: Callable[[], float] = time.time,
        on_exit: Callable[[], None] | None = None,
    ) -> None:
        self.cell = cell
        self._on_exit = on_exit
        self._source = source
        self._link = link
        self._metrics = metrics
        self._clock = clock
        self._servo_cadence = Cadence.per_second(settings.servo_hz)
        self._frame_cadence = Cadence.per_second(settings.frame_fps)
        self._stop = threading.Event()
        self._problems = RateLimitedLog(log, 60.0)
        self._thread = threading.Thread(target=self._loop, name=f"armnet-telemetry-{cell}", daemon=True)

    def start(self) -> CellTelemetry:
        self._thread.start()
        return self

    def stop(self) -> None:
        """Ask the thread to end; it does after the read under way (never waited for here)."""
        self._stop.set()

    def join(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for the thread to end; True when it has."""
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def _loop(self) -> None:
        try:
            self._run()
        finally:
            if self._on_exit is not None:
                try:
                    self._on_exit()
                except Exception:  # noqa: BLE001 - closing devices at exit is best effort
                    log.warning("cell %s: closing telemetry devices failed", self.cell, exc_info=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.tick(time.monotonic())
            except Exception as exc:  # noqa: BLE001 - telemetry must never take the worker down
                log.debug("cell %s: telemetry tick failed", self.cell, exc_info=True)
                self._problems.warning("cell %s: telemetry tick failed: %s: %s", self.cell, type(exc).__name__, exc)
            now = time.monotonic()
            waits = [c.wait_s(now) for c in (self._servo_cadence, self._frame_cadence) if c.enabled]
            self._stop.wait(min(waits) if waits else 1.0)

    def tick(self, now: float) -> None:
        """Publish what is due at ``now`` (monotonic)."""
        servos_due, self._servo_cadence = self._servo_cadence.due(now)
        frames_due, self._frame_cadence = self._frame_cadence.due(now)
        if not (servos_due or frames_due):
            return
        source = self._source()
        if source is None:
            return
        if servos_due:
            self.publish_servos(source)
        if frames_due:
            self.publish_frames(source)

    def publish_servos(self, source: TelemetrySource) -> None:
        readings = source.servos()
        if readings is None:
            self._metrics.telemetry_reads.labels(result="skipped").inc()
            return
        payload = servos_payload(self._clock(), source.name, readings)
        self._link.notify(servos_subject(self.cell), payload)
        self._metrics.telemetry_reads.labels(result="published").inc()
        verdict = source.monitor()
        if verdict is not None:
            self._link.notify(monitor_subject(self.cell), monitor_payload(
                self._clock(), verdict.complete, verdict.score, verdict.frame_at))

    def publish_frames(self, source: TelemetrySource) -> None:
        for camera, frame in list(sorted(source.frames().items()))[:MAX_CAMERAS]:
            if isinstance(frame, str):
                self._metrics.telemetry_frames.labels(result="failed").inc()
                self._problems.warning("cell %s: no frame from camera %s: %s", self.cell, camera, frame)
                continue
            try:
                jpeg = encode_jpeg(frame)
                subject = camera_subject(self.cell, camera)
            except ValueError as exc:
                self._metrics.telemetry_frames.labels(result="failed").inc()
                self._problems.warning("cell %s: camera %s frame not published: %s", self.cell, camera, exc)
                continue
            self._link.notify(subject, jpeg)
            self._metrics.telemetry_frames.labels(result="published").inc()
