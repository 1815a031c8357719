"""Building the real (or simulated) device objects a job asks for, on the cell's devices.

This module owns the mapping from what the customer passes (a connector
endpoint as ``port``, a camera name as ``index_or_path``) to the cell's real
devices, and the construction of the allow-listed classes. It never decides
what a job may call on them (``allowlist``/``session`` do).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from armnet_runtime.endpoints import parse_endpoint

from .config import ArmConfig, CameraConfig, ConnectorConfig, MotorRange
from .errors import RequestError, not_allowed
from .identity import CellMotor, JobMotor, cell_motor_table, motors_refusal, protocol_refusal
from .interlock import Interlock
from .policed_bus import BusPolicy, policed_bus_class
from .report import SafetyRecorder
from .restore import RegisterLedger

log = logging.getLogger(__name__)

#: Builds the camera served for a request: (camera name, cell camera settings, the
#: customer's camera config with ``index_or_path`` already mapped) -> a LeRobot Camera.
CameraFactory = Callable[[str, CameraConfig, Any], Any]


@dataclass
class Handle:
    """A live object of one connection: the real object plus what the customer sees of it."""

    class_name: str
    obj: Any
    lock: DeviceLock
    #: Attribute values shown to the customer instead of the real ones (``port``, ``config``).
    overrides: dict[str, Any] = field(default_factory=dict)
    arm: str | None = None
    #: The cell's name of a camera object's camera (its video in the cell's record is named so).
    camera: str | None = None
    arm_config: ArmConfig | None = None
    cell_ranges: dict[str, MotorRange] = field(default_factory=dict)
    #: The cell's motors of this bus (a job's ``motors`` are checked to be exactly these).
    cell_motors: dict[str, CellMotor] = field(default_factory=dict)
    #: The cell lets this job run LeRobot's calibration methods (``allowCalibrationJobs``).
    allow_calibration: bool = False
    #: Latest Present_Position sync_read, per ``normalize`` flag: (monotonic time, values).
    present: dict[bool, tuple[float, dict[str, float]]] = field(default_factory=dict)
    #: The safety facts of the motors last written, with the values they were built from.
    facts_cache: tuple[tuple[Any, ...], dict[str, Any]] | None = None
    #: Counts the calls that may have changed the bus's calibration (``motion.KEEPS_CALIBRATION``).
    calibration_epoch: int = 0
    #: ``calibration_epoch`` when ``facts_cache`` was last compared with the bus by value.
    facts_epoch: int = -1
    #: The goal rules compiled from those facts: (facts, relative limit, {normalize: (rules, their GoalScreen)}).
    limits_cache: tuple[dict[str, Any], Any, dict[bool, Any]] | None = None


#: How long a request waits for a device another request is using before it is refused.
#: A capped bus call (``buscaps``) ends well within it; only a wedged device exceeds it.
DEVICE_LOCK_WAIT_S = 5.0


class DeviceLock:
    """A re-entrant lock on one device whose ``with`` gives up after a deadline.

    Why not a bare ``RLock``: a call that never ends (a job's hostile retry count,
    a wedged driver) would make every later request, and the connector's own
    stop, wait on it forever. ``with lock:`` waits at most ``wait_s`` and then
    raises ``RequestError("DeviceBusy")``, which the job sees as a clear error.
    """

    def __init__(self, name: str, wait_s: float = DEVICE_LOCK_WAIT_S) -> None:
        self.name = name
        self.wait_s = wait_s
        self._lock = threading.RLock()

    def acquire(self, timeout: float) -> bool:
        return self._lock.acquire(timeout=max(0.0, timeout))

    def release(self) -> None:
        self._lock.release()

    def __enter__(self) -> DeviceLock:
        if not self._lock.acquire(timeout=self.wait_s):
            raise RequestError(
                "DeviceBusy",
                f"device {self.name} stayed busy with another call for {self.wait_s:g} s; this call was "
                "not sent. Use one connection per device, or retry once the other call has ended",
            )
        return self

    def __exit__(self, *exc: object) -> None:
        self._lock.release()


class DeviceLocks:
    """One lock per device: LeRobot's PortHandler is not thread-safe (docs/reference/feetech-lerobot.md, §1)."""

    def __init__(self, wait_s: float = DEVICE_LOCK_WAIT_S) -> None:
        self._locks: dict[str, DeviceLock] = {}
        self._guard = threading.Lock()
        self._wait_s = wait_s

    def get(self, key: str) -> DeviceLock:
        with self._guard:
            lock = self._locks.get(key)
            if lock is None:
                lock = self._locks[key] = DeviceLock(key, self._wait_s)
            return lock


def _bind(cls: type, args: list[Any], kwargs: dict[str, Any]) -> inspect.BoundArguments:
    try:
        return inspect.signature(cls).bind(*args, **kwargs)
    except TypeError as exc:
        raise RequestError("TypeError", f"{cls.__name__}(...): {exc}") from None


def arm_selector(port: Any, config: ConnectorConfig) -> str | None:
    """The arm named by the customer's ``port``: a connector endpoint (``?arm=``) or an arm name."""
    if isinstance(port, str) and port in config.arms:
        return port
    if not isinstance(port, str):
        raise not_allowed(f"port must be this cell's connector endpoint (a string), got {type(port).__name__}")
    try:
        return parse_endpoint(port).arm
    except ValueError:
        raise not_allowed(
            f"port {port!r} is not this cell's connector endpoint; pass ctx.cell's port "
            "(ARMNET_CELL_SOCKET, with ?arm=NAME on multi-arm cells): the connector maps it to the arm"
        ) from None


def cell_motors_of(arm: ArmConfig, ranges: dict[str, MotorRange]) -> dict[str, CellMotor]:
    """The arm's motor table: ids from the cell's calibration, units from the cell (or the SO-101's)."""
    return cell_motor_table({m: r.id for m, r in ranges.items()}, arm.motor_model, arm.norm_modes)


def _job_motors(motors: Any) -> dict[str, JobMotor]:
    from lerobot.motors import Motor

    if not isinstance(motors, dict) or not all(isinstance(k, str) and isinstance(v, Motor) for k, v in motors.items()):
        raise not_allowed(
            f"motors must be a dict of motor name -> lerobot.motors.Motor, got {type(motors).__name__}"
        )
    return {
        name: JobMotor(m.id, m.model, getattr(m.norm_mode, "value", m.norm_mode)) for name, m in motors.items()
    }


def _cell_calibration(motors: dict[str, Any], ranges: dict[str, MotorRange]) -> dict[str, Any]:
    from lerobot.motors import MotorCalibration

    return {
        name: MotorCalibration(r.id, r.drive_mode, r.homing_offset, r.range_min, r.range_max)
        for name, r in ranges.items() if name in motors
    }


def _calibration_refusal(given: Any, cell: dict[str, Any]) -> str | None:
    """Why a job's ``calibration`` argument is refused: it must be absent or the cell's own."""
    if given is None:
        return None
    if not isinstance(given, dict):
        return f"calibration must be a dict of motor name -> MotorCalibration or None, got {type(given).__name__}"
    for name, entry in given.items():
        if name not in cell or entry != cell[name]:
            return (
                f"calibration for motor {str(name)[:64]!r} is not this cell's ({cell.get(name)!r}); the cell's "
                "calibration applies to every job: pass None or the file at ctx.cell.calibration_dir"
            )
    return None


def create_feetech(
    args: list[Any], kwargs: dict[str, Any], config: ConnectorConfig, locks: DeviceLocks,
    ranges: dict[str, dict[str, MotorRange]], *, interlock: Interlock, recorder: SafetyRecorder,
    end_recording: Callable[[float], bool] | None = None, on_lost_reply: Callable[[], None] | None = None,
    ledger_for: Callable[[str], RegisterLedger] | None = None,
) -> Handle:
    """The job's bus, built from the cell's description: the job only chooses a subset of its motors.

    Checked before anything is built (so a refused request changes nothing, not even
    scservo_sdk's process-global byte order): the port maps to an arm of the cell;
    every motor is the cell's, with its id, model and unit; the calibration is absent
    or the cell's; the protocol is the motors' own. The bus gets the cell's calibration,
    and ``ledger_for(arm)``: where it notes what the job's writes change (``restore``).
    """
    from lerobot.motors.feetech import FeetechMotorsBus

    bound = _bind(FeetechMotorsBus, args, kwargs)
    port = bound.arguments.get("port")
    try:
        arm_name, arm = config.arm_for(arm_selector(port, config))
    except KeyError as exc:
        raise RequestError("KeyError", str(exc.args[0])) from None
    arm_ranges = ranges.get(arm_name, {})
    if not arm_ranges:
        raise not_allowed(
            f"arm {arm_name!r} has no calibration file on this cell: the connector does not know its motors, "
            "so it serves no bus on it (the cell's owner must provide the calibration)"
        )
    cell = cell_motors_of(arm, arm_ranges)
    job = _job_motors(bound.arguments.get("motors"))
    why = motors_refusal(job, cell)
    if why is None:
        models = {cell[m].model for m in job} or {motor.model for motor in cell.values()}
        why = protocol_refusal(bound.arguments.get("protocol_version", 0), models)
    cell_calibration = _cell_calibration(job, arm_ranges)
    if why is None:
        why = _calibration_refusal(bound.arguments.get("calibration"), cell_calibration)
    if why is not None:
        raise not_allowed(why)
    from lerobot.motors import Motor, MotorNormMode

    # The cell's ids and models; the job's unit where the cell accepts it (identity.ALSO_ACCEPTED).
    motors = {m: Motor(cell[m].id, cell[m].model, MotorNormMode(str(job[m].norm_mode))) for m in job}
    policy = BusPolicy(
        arm_name, {cell[m].id: (m, cell[m]) for m in cell}, interlock, recorder,
        bounds=dict(config.register_bounds), allow_calibration=config.allow_calibration_jobs,
        calibration={r.id: (r.homing_offset, r.range_min, r.range_max) for r in arm_ranges.values()},
    )
    if end_recording is not None:
        policy = dataclasses.replace(policy, end_recording=end_recording)
    if on_lost_reply is not None:
        policy = dataclasses.replace(policy, on_lost_reply=on_lost_reply)
    if ledger_for is not None:
        policy = dataclasses.replace(policy, ledger=ledger_for(arm_name))
    obj = policed_bus_class()(port=arm.port, motors=motors, calibration=cell_calibration, armnet_policy=policy)
    return Handle(
        "FeetechMotorsBus", obj, locks.get(arm.port), overrides={"port": port},
        arm=arm_name, arm_config=arm, cell_ranges=arm_ranges, cell_motors={m: cell[m] for m in job},
        allow_calibration=config.allow_calibration_jobs,
    )


def find_camera(index_or_path: Any, config: ConnectorConfig) -> tuple[str, CameraConfig]:
    """The cell camera a customer's ``index_or_path`` names (by camera name or configured index/path)."""
    wanted = str(index_or_path)
    if wanted in config.cameras:
        return wanted, config.cameras[wanted]
    for name, camera in config.cameras.items():
        if str(camera.index_or_path) == wanted:
            return name, camera
    raise not_allowed(
        f"camera {index_or_path!r} is not a camera of this cell; use one of {sorted(config.cameras)} "
        "(ctx.camera_configs lists them)"
    )


def device_camera_config(requested: Any, camera: CameraConfig) -> Any:
    """The customer's camera config pointed at the cell's device (other settings are the customer's)."""
    source: int | Path = camera.index_or_path if isinstance(camera.index_or_path, int) else Path(camera.index_or_path)
    return dataclasses.replace(requested, index_or_path=source)


def opencv_camera_factory(name: str, camera: CameraConfig, requested: Any) -> Any:
    from lerobot.cameras.opencv import OpenCVCamera

    return OpenCVCamera(device_camera_config(requested, camera))


def simulated_camera_factory(source: Any = None) -> CameraFactory:
    """Serves ``OpenCVCamera`` requests with the simulator's camera, drawing ``source``'s joints."""

    def build(name: str, camera: CameraConfig, requested: Any) -> Any:
        from armnet_sim.camera import SimulatedCamera

        return SimulatedCamera(requested, source=source)

    return build


def create_camera(
    args: list[Any], kwargs: dict[str, Any], config: ConnectorConfig, locks: DeviceLocks,
    factory: CameraFactory,
) -> Handle:
    from lerobot.cameras.opencv import OpenCVCamera, OpenCVCameraConfig

    bound = _bind(OpenCVCamera, args, kwargs)
    requested = bound.arguments.get("config")
    if not isinstance(requested, OpenCVCameraConfig):
        raise RequestError(
            "TypeError", f"OpenCVCamera(config) needs an OpenCVCameraConfig, got {type(requested).__name__}"
        )
    name, camera = find_camera(requested.index_or_path, config)
    obj = factory(name, camera, requested)
    return Handle(
        "OpenCVCamera", obj, locks.get(f"camera:{name}"),
        overrides={"config": requested, "index_or_path": requested.index_or_path}, camera=name,
    )


def create_arx5(args: list[Any], kwargs: dict[str, Any], locks: DeviceLocks) -> Handle:
    try:
        module = importlib.import_module("lerobot.robots.arx5")
    except ImportError:
        raise not_allowed(
            "ARX5Arm is not available on this cell: its SDK is not installed on the connector"
        ) from None
    cls = getattr(module, "ARX5Arm", None)
    if cls is None:
        raise not_allowed("ARX5Arm is not available on this cell's ARX5 SDK")
    bound = _bind(cls, args, kwargs)
    return Handle("ARX5Arm", cls(*bound.args, **bound.kwargs), locks.get("arx5"))
