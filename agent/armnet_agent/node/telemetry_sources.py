"""Where a cell's telemetry comes from: the agent while the cell is idle, the job's connector while it runs.

``IdleSource`` reads the servos with plain ``scservo_sdk`` on the cell's ports,
taking its turn on the bus like the health probe (``BusTurns``): a launch waits
for a read under way, and nothing is read once a job holds the bus. A simulated
cell's cameras are drawn from its simulator (no device is opened); a real cell's
cameras are opened by the agent while idle and closed before a job starts
(``release``), so the job's connector finds them free.

``JobSource`` reads through the job's connector when it runs in this process
(``connector.telemetry``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from armnet_agent.connector.config import read_calibration_file
from armnet_agent.connector.telemetry import (
    CameraFrame,
    ServoSample,
    latest_frames,
    name_samples,
    read_cell_servos,
    read_port,
)
from armnet_agent.launch.cell_spec import CameraSpec
from armnet_agent.node.bus_turns import BusTurns
from armnet_agent.node.probes import SO101_MOTOR_NAMES
from armnet_agent.node.telemetry_wire import scaled_size
from armnet_agent.sim.presets import SimulatedCell

log = logging.getLogger(__name__)

#: An arm the idle source reads: (serial port, calibration file or None).
ArmPort = tuple[str, Path | None]


def servo_ids(calibration_file: Path | None) -> dict[str, int]:
    """motor -> servo id: the calibration file's, else the SO-101's factory ids."""
    if calibration_file is not None and calibration_file.is_file():
        try:
            return {motor: r.id for motor, r in read_calibration_file(calibration_file).items()}
        except (OSError, ValueError):
            pass
    return {motor: index + 1 for index, motor in enumerate(SO101_MOTOR_NAMES)}


def simulated_frames(sim: SimulatedCell, cameras: tuple[CameraSpec, ...]) -> dict[str, CameraFrame | str]:
    """Each camera's picture drawn from the simulator's joints (the simulated cell's camera stand-in)."""
    from armnet_agent.sim.render import render_arms

    angles = sim.joint_angles()
    # Drawn at the published size: no pixels are drawn only to be scaled away.
    return {camera.name: CameraFrame(render_arms(angles, *scaled_size(camera.width, camera.height)))
            for camera in cameras}


class IdleCameras:
    """A real cell's cameras, opened by the agent while no job runs; ``close`` before a launch."""

    def __init__(self) -> None:
        self._open: dict[str, Any] = {}

    def frames(self, cameras: tuple[CameraSpec, ...]) -> dict[str, CameraFrame | str]:
        frames: dict[str, CameraFrame | str] = {}
        for spec in cameras:
            if spec.index_or_path is None:
                frames[spec.name] = "no device configured (spec.cameras.<name>.indexOrPath)"
                continue
            try:
                camera = self._open.get(spec.name) or self._connect(spec)
                frames[spec.name] = CameraFrame(camera.async_read(timeout_ms=500))
            except Exception as exc:  # noqa: BLE001 - one failing camera must not stop the others
                frames[spec.name] = f"{type(exc).__name__}: {str(exc)[:200]}"
                self._close(spec.name)
        return frames

    def _connect(self, spec: CameraSpec) -> Any:
        from lerobot.cameras.opencv import OpenCVCamera, OpenCVCameraConfig

        source = spec.index_or_path if isinstance(spec.index_or_path, int) else Path(str(spec.index_or_path))
        camera = OpenCVCamera(OpenCVCameraConfig(index_or_path=source, fps=spec.fps, width=spec.width,
                                                 height=spec.height))
        camera.connect(warmup=False)
        self._open[spec.name] = camera
        return camera

    def _close(self, name: str) -> None:
        camera = self._open.pop(name, None)
        if camera is not None:
            try:
                camera.disconnect()
            except Exception as exc:  # noqa: BLE001 - closing a broken camera is best effort
                log.debug("closing camera %s: %s", name, exc)

    def close(self) -> None:
        for name in list(self._open):
            self._close(name)


class IdleSource:
    """The agent's own readings of an idle cell."""

    name = "idle"

    def __init__(
        self,
        arms: Mapping[str, ArmPort],
        cameras: tuple[CameraSpec, ...],
        turns: BusTurns,
        bus_held: Callable[[], bool],
        sim: SimulatedCell | None,
        real_cameras: IdleCameras,
    ) -> None:
        self._arms = arms
        self._cameras = cameras
        self._turns = turns
        self._bus_held = bus_held
        self._sim = sim
        self._real_cameras = real_cameras

    def servos(self) -> Mapping[str, Mapping[str, ServoSample | None] | str] | None:
        return self._turns.probe(self._read_servos, bus_held=self._bus_held)

    def _read_servos(self) -> dict[str, Mapping[str, ServoSample | None] | str]:
        readings: dict[str, Mapping[str, ServoSample | None] | str] = {}
        for arm, (port, calibration) in self._arms.items():
            ids = servo_ids(calibration)
            try:
                readings[arm] = name_samples(ids, read_port(port, ids.values()))
            except OSError as exc:
                readings[arm] = str(exc)[:200]
        return readings

    def frames(self) -> Mapping[str, CameraFrame | str]:
        if self._sim is not None:
            return simulated_frames(self._sim, self._cameras)
        frames = self._turns.probe(lambda: self._real_cameras.frames(self._cameras), bus_held=self._bus_held)
        return frames if frames is not None else {}


class JobSource:
    """Readings through the running job's connector (in this process)."""

    name = "job"

    def __init__(self, cell: Any, cameras: tuple[CameraSpec, ...], sim: SimulatedCell | None) -> None:
        self._cell = cell
        self._cameras = cameras
        self._sim = sim

    def servos(self) -> Mapping[str, Mapping[str, ServoSample | None] | str] | None:
        if self._cell.stopping.is_set():
            return None  # the connector is releasing the arms (rest, torque off): leave the bus to it
        return read_cell_servos(self._cell)

    def frames(self) -> Mapping[str, CameraFrame | str]:
        frames: dict[str, CameraFrame | str] = dict(latest_frames(self._cell))
        missing = tuple(c for c in self._cameras if c.name not in frames)
        if missing and self._sim is not None:
            frames.update(simulated_frames(self._sim, missing))  # the simulator is no device: draw it
        for camera in missing:
            frames.setdefault(camera.name, "the job has not opened this camera (its connector owns it)")
        return frames
