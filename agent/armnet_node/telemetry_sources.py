"""Where a cell's telemetry comes from: the agent while the cell is idle, the job's connector while it runs.

``IdleSource`` reads the servos through the agent's own handle on each arm's
port (``IdleArms``: kept open between reads, only for Feetech arms), taking its
turn on the bus like the health probe (``BusTurns``): a launch waits for a read
under way and closes the handles in its turn, and nothing is read once a job
holds the bus. A simulated cell's cameras are drawn from its simulator (no
device is opened); a real cell's cameras are opened by the agent while idle
(``IdleCameras``), never under the bus turn: a slow or hung camera delays no
launch nor heartbeat. A launch closes them with a bounded wait.

``JobSource`` publishes what the job's connector already knows (a ``JobView``):
the positions of the job's own reads, its cameras' latest frames, and the cell's
completion monitor's verdict now. The view
is ``InProcessView`` for a connector in this process and the pod sidecar's
observer socket (``node.sidecar_observer``) for a pod job: one path for both.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from armnet_connector.config import DEFAULT_MOTOR_MODEL, read_calibration_file
from armnet_connector.inputs import MonitorVerdict
from armnet_connector.telemetry import (
    ArmReader,
    CameraFrame,
    job_servos,
    latest_frames,
    monitor_now,
)
from armnet_connector.telemetry_decode import ServoSample, feetech_protocol, name_samples
from armnet_core import BIMANUAL_SO101_EMBODIMENT, SO101_EMBODIMENT
from armnet_core.backoff import BackoffPolicy
from armnet_launch.cell_spec import CameraSpec
from armnet_sim.presets import CellSimulator

from armnet_node.bus_turns import BusTurns
from armnet_node.probes import SO101_MOTOR_NAMES
from armnet_node.telemetry_wire import scaled_size

if TYPE_CHECKING:
    from armnet_connector.cell import CellState

log = logging.getLogger(__name__)


#: The servos of each embodiment the platform knows (a Cell declares its motors by its embodiment;
#: the connector's ``motorModel`` defaults to the same): every SO-101 joint is a Feetech STS3215.
EMBODIMENT_MOTOR_MODEL: Mapping[str, str] = {
    SO101_EMBODIMENT: DEFAULT_MOTOR_MODEL,
    BIMANUAL_SO101_EMBODIMENT: DEFAULT_MOTOR_MODEL,
}


@dataclass(frozen=True)
class ArmPort:
    """An arm the idle source reads: its serial port, calibration file, and motor model (None: unknown)."""

    port: str
    calibration: Path | None = None
    motor_model: str | None = DEFAULT_MOTOR_MODEL


def servo_ids(calibration_file: Path | None) -> dict[str, int]:
    """motor -> servo id: the calibration file's, else the SO-101's factory ids."""
    if calibration_file is not None and calibration_file.is_file():
        try:
            return {motor: r.id for motor, r in read_calibration_file(calibration_file).items()}
        except (OSError, ValueError):
            pass
    return {motor: index + 1 for index, motor in enumerate(SO101_MOTOR_NAMES)}


def simulated_frames(sim: CellSimulator, cameras: tuple[CameraSpec, ...]) -> dict[str, CameraFrame | str]:
    """Each camera's picture drawn from the simulator's joints (the simulated cell's camera stand-in)."""
    from armnet_sim.render import render_arms

    angles = sim.joint_angles()
    # Drawn at the published size: no pixels are drawn only to be scaled away.
    return {camera.name: CameraFrame(render_arms(angles, *scaled_size(camera.width, camera.height)))
            for camera in cameras}


CAMERA_READ_TIMEOUT_MS = 500
CAMERA_BACKOFF = BackoffPolicy(first_s=1.0, max_s=60.0)
"""A failing camera is retried after 1, 2, 4 ... s, at most a minute apart (not reopened every tick)."""


class IdleCameras:
    """A real cell's cameras, opened by the agent while no job runs; ``close`` before a launch.

    Cameras are kept per ``CameraSpec`` (a Cell whose camera changed opens the new
    one and closes the old). Their own lock, never the bus's: a hung device stalls
    only this. ``close(wait_s)`` waits a bounded time for a read under way; when it
    cannot, the camera thread closes them itself as soon as its read returns, and
    opens nothing more until ``resume``.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._open: dict[CameraSpec, Any] = {}
        self._failures: dict[CameraSpec, tuple[int, float]] = {}  # spec -> (failures in a row, retry at)
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._clock = clock

    def frames(self, cameras: tuple[CameraSpec, ...], wait_s: float = 0.1) -> dict[str, CameraFrame | str]:
        """Each camera's latest frame or why there is none; {} when a close holds the cameras."""
        if self._closing.is_set() or not self._lock.acquire(timeout=wait_s):
            return {}
        try:
            if self._closing.is_set():
                return {}
            for stale in [spec for spec in self._open if spec not in cameras]:
                self._close(stale)  # the Cell changed this camera (or dropped it): the old device goes
            for gone in [spec for spec in self._failures if spec not in cameras]:
                del self._failures[gone]
            return {spec.name: self._frame(spec) for spec in cameras}
        finally:
            if self._closing.is_set():
                self._close_all()
            self._lock.release()

    def _frame(self, spec: CameraSpec) -> CameraFrame | str:
        if spec.index_or_path is None:
            return "no device configured (spec.cameras.<name>.indexOrPath)"
        failures, retry_at = self._failures.get(spec, (0, 0.0))
        now = self._clock()
        if now < retry_at:
            return f"failed {failures} time(s) in a row; retried in {retry_at - now:.0f} s"
        try:
            camera = self._open.get(spec) or self._connect(spec)
            frame = CameraFrame(camera.async_read(timeout_ms=CAMERA_READ_TIMEOUT_MS))
        except Exception as exc:  # noqa: BLE001 - one failing camera must not stop the others
            self._close(spec)
            self._failures[spec] = (failures + 1, self._clock() + CAMERA_BACKOFF.delay(failures + 1))
            return f"{type(exc).__name__}: {str(exc)[:200]}"
        self._failures.pop(spec, None)
        return frame

    def _connect(self, spec: CameraSpec) -> Any:
        from lerobot.cameras.opencv import OpenCVCamera, OpenCVCameraConfig

        source = spec.index_or_path if isinstance(spec.index_or_path, int) else Path(str(spec.index_or_path))
        camera = OpenCVCamera(OpenCVCameraConfig(index_or_path=source, fps=spec.fps, width=spec.width,
                                                 height=spec.height))
        camera.connect(warmup=False)
        self._open[spec] = camera
        return camera

    def _close(self, spec: CameraSpec) -> None:
        camera = self._open.pop(spec, None)
        if camera is not None:
            try:
                camera.disconnect()
            except Exception as exc:  # noqa: BLE001 - closing a broken camera is best effort
                log.debug("closing camera %s: %s", spec.name, exc)

    def _close_all(self) -> None:
        for spec in list(self._open):
            self._close(spec)

    @property
    def open_count(self) -> int:
        return len(self._open)

    @property
    def suspended(self) -> bool:
        """Closed for a launch (or the agent's stop): nothing opens until ``resume``."""
        return self._closing.is_set()

    def close(self, wait_s: float = 2.0) -> bool:
        """Close every camera and open none until ``resume``; False when a read held them past ``wait_s``.

        Then the reading thread closes them as its read returns.
        """
        self._closing.set()
        if not self._lock.acquire(timeout=wait_s):
            log.warning("an idle camera read is still under way after %.1f s; it closes its cameras when it "
                        "returns", wait_s)
            return False
        try:
            self._close_all()
        finally:
            self._lock.release()
        return True

    def resume(self) -> bool:
        """Let ``frames`` open cameras again (the cell is idle again)."""
        self._closing.clear()
        return True


class IdleArms:
    """The agent's own handle on each idle arm's port, kept open between reads; ``close`` before a launch."""

    def __init__(self) -> None:
        self._readers: dict[tuple[str, int], ArmReader] = {}
        self._lock = threading.Lock()

    def read(self, arm: ArmPort, ids: Mapping[str, int]) -> dict[str, ServoSample | None] | str:
        protocol = feetech_protocol(arm.motor_model)
        if protocol is None:
            return (f"motor model {arm.motor_model!r} is no Feetech servo: the agent reads only Feetech "
                    "(STS/SMS) arms")
        with self._lock:
            reader = self._readers.get((arm.port, protocol))
            if reader is None:
                reader = self._readers[(arm.port, protocol)] = ArmReader(arm.port, protocol)
        try:
            return name_samples(ids, reader.read(ids.values()))
        except OSError as exc:
            return str(exc)[:200]

    @property
    def readers(self) -> list[ArmReader]:
        """The handles made so far (open until ``close``)."""
        with self._lock:
            return list(self._readers.values())

    def close(self) -> None:
        with self._lock:
            readers, self._readers = list(self._readers.values()), {}
        for reader in readers:
            reader.close()


class IdleSource:
    """The agent's own readings of an idle cell."""

    name = "idle"

    def __init__(
        self,
        arms: Mapping[str, ArmPort],
        cameras: tuple[CameraSpec, ...],
        turns: BusTurns,
        bus_held: Callable[[], bool],
        sim: CellSimulator | None,
        real_cameras: IdleCameras,
        handles: IdleArms,
    ) -> None:
        self._arms = arms
        self._cameras = cameras
        self._turns = turns
        self._bus_held = bus_held
        self._sim = sim
        self._real_cameras = real_cameras
        self._handles = handles

    def servos(self) -> Mapping[str, Mapping[str, ServoSample | None] | str] | None:
        return self._turns.probe(self._read_servos, bus_held=self._bus_held)

    def monitor(self) -> MonitorVerdict | None:
        return None  # the completion monitor runs in a job's connector only

    def _read_servos(self) -> dict[str, Mapping[str, ServoSample | None] | str]:
        return {name: self._handles.read(arm, servo_ids(arm.calibration)) for name, arm in self._arms.items()}

    def frames(self) -> Mapping[str, CameraFrame | str]:
        if self._sim is not None:
            return simulated_frames(self._sim, self._cameras)
        # Cameras open again only in the bus's turn with no job (a launch closes them in its turn);
        # the reads themselves run outside it.
        if self._real_cameras.suspended and self._turns.probe(self._real_cameras.resume,
                                                               bus_held=self._bus_held) is None:
            return {}
        return self._real_cameras.frames(self._cameras)


class JobView(Protocol):
    """What a running job's connector knows, wherever it runs: this process, or a pod's sidecar."""

    def servos(self) -> Mapping[str, Mapping[str, ServoSample | None] | str] | None:
        """arm -> motor -> the position of the job's last read (or why none); None once the job is stopping."""
        ...

    def frames(self) -> Mapping[str, CameraFrame]:
        """camera -> the latest frame of each camera the job opened."""
        ...

    def monitor(self) -> MonitorVerdict | None:
        """The cell's completion monitor's verdict now; None on a cell that scores nothing, or once stopping."""
        ...


class InProcessView:
    """A connector in this process (the container launcher, ``armnet run``): read from its memory."""

    def __init__(self, cell: CellState) -> None:
        self._cell = cell

    def servos(self) -> Mapping[str, Mapping[str, ServoSample | None] | str] | None:
        return job_servos(self._cell)

    def frames(self) -> Mapping[str, CameraFrame]:
        return latest_frames(self._cell)

    def monitor(self) -> MonitorVerdict | None:
        return monitor_now(self._cell)


class JobSource:
    """What the running job's connector already knows (``JobView``): no traffic on the job's bus."""

    name = "job"

    def __init__(self, view: JobView, cameras: tuple[CameraSpec, ...], sim: CellSimulator | None) -> None:
        self._view = view
        self._cameras = cameras
        self._sim = sim

    def servos(self) -> Mapping[str, Mapping[str, ServoSample | None] | str] | None:
        return self._view.servos()

    def monitor(self) -> MonitorVerdict | None:
        return self._view.monitor()

    def frames(self) -> Mapping[str, CameraFrame | str]:
        frames: dict[str, CameraFrame | str] = dict(self._view.frames())
        missing = tuple(c for c in self._cameras if c.name not in frames)
        if missing and self._sim is not None:
            frames.update(simulated_frames(self._sim, missing))  # the simulator is no device: draw it
        for camera in missing:
            frames.setdefault(camera.name, "the job has not opened this camera (its connector owns it)")
        return frames
