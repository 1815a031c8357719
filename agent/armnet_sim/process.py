"""Run a simulated cell in a child process and drive it from this one.

Why: the SDK client busy-polls the serial port while holding the GIL. In the
same process, the simulator thread must win the GIL *and* a CPU within
LeRobot's ~50 ms timeout; on a loaded machine the GIL holder is sometimes
descheduled and replies come too late. A child process only needs a CPU, and
a process that sleeps in ``select`` is woken promptly by the scheduler.

The child runs the ordinary threaded ``SimulatedCell``; this module forwards
the read-back and fault-injection calls of each arm over a pipe.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import signal
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .arm import MotorSpec
from .calibration import Calibration, MotorCalibration
from .lifecycle import StartStop

#: Arm methods the parent may call in the child; nothing else crosses the pipe.
REMOTE_METHODS = frozenset(
    {
        "positions",
        "goal_positions",
        "register",
        "torque_enabled",
        "joint_angles",
        "normalized_positions",
        "is_moving",
        "block",
        "move_by_hand",
        "unplug",
        "plug",
        "corrupt_replies",
        "drop_replies",
        "send_stale_acks",
        "set_error_bits",
        "overload",
        "clear_faults",
        "power_cycle",
        "set_latency_ms",
    }
)
START_TIMEOUT_S = 60.0


class SimulatorProcessError(RuntimeError):
    """The simulator child process failed to start or died."""


class RemoteArm:
    """The parent-side handle of one arm simulated in the child process.

    It offers the read-back and fault methods of ``SimulatedArm`` (see
    ``REMOTE_METHODS``) plus ``name``, ``port``, ``motors`` and ``calibration``.
    """

    def __init__(
        self,
        owner: SimulatedCellProcess,
        name: str,
        port: str,
        motors: dict[str, MotorSpec],
        calibration: dict[str, MotorCalibration],
    ) -> None:
        self._owner = owner
        self.name = name
        self.port = port
        self.motors = motors
        self.calibration = calibration

    def __getattr__(self, method: str) -> Any:
        if method not in REMOTE_METHODS:
            raise AttributeError(f"{type(self).__name__} has no attribute {method!r}")

        def call(*args: Any, **kwargs: Any) -> Any:
            return self._owner.call(self.name, method, args, kwargs)

        call.__name__ = method
        return call


class SimulatedCellProcess(StartStop):
    """A ``SimulatedCell`` living in a child process; same surface, arms are ``RemoteArm``s."""

    def __init__(
        self,
        preset: str,
        *,
        calibrations: Mapping[str, Calibration] | None = None,
        latency_ms: float = 0.0,
        link_dir: str | Path | None = None,
        start_method: str | None = None,
        state_dir: str | Path | None = None,
    ) -> None:
        from .presets import PRESETS

        if preset not in PRESETS:
            raise ValueError(
                f"unknown simulator preset {preset!r}; choose one of {sorted(PRESETS)}"
            )
        self.preset = preset
        self._options = {
            "calibrations": {k: dict(v) for k, v in (calibrations or {}).items()},
            "latency_ms": latency_ms,
            "link_dir": str(link_dir) if link_dir is not None else None,
            "state_dir": str(state_dir) if state_dir is not None else None,
        }
        self._start_method = start_method
        self._conn: multiprocessing.connection.Connection | None = None
        self._process: multiprocessing.process.BaseProcess | None = None
        self._lock = threading.Lock()
        self.arms: dict[str, RemoteArm] = {}

    @property
    def arm(self) -> RemoteArm:
        if len(self.arms) != 1:
            raise ValueError(
                f"cell {self.preset!r} has arms {list(self.arms)}; pick one from .arms"
            )
        return next(iter(self.arms.values()))

    def ports(self) -> dict[str, str]:
        return {name: arm.port for name, arm in self.arms.items()}

    def joint_angles(self) -> dict[str, dict[str, float]]:
        return {name: arm.joint_angles() for name, arm in self.arms.items()}

    def start(self) -> SimulatedCellProcess:
        if self._process is not None:
            raise RuntimeError("simulator process already started")
        # fork is fast and safe while this process has no other thread; else spawn.
        method = self._start_method or ("fork" if threading.active_count() == 1 else "spawn")
        ctx = multiprocessing.get_context(method)
        parent, child = ctx.Pipe()
        process = ctx.Process(  # type: ignore[attr-defined]  # typeshed: BaseContext lacks Process
            target=_child_main,
            args=(child, self.preset, self._options),
            name=f"armnet-sim-{self.preset}",
            daemon=True,
        )
        process.start()
        child.close()
        self._conn, self._process = parent, process
        if not parent.poll(START_TIMEOUT_S):
            self.stop()
            raise SimulatorProcessError(f"simulator for {self.preset!r} did not start in time")
        try:
            status, payload = parent.recv()
        except EOFError:
            self.stop()
            raise SimulatorProcessError(
                f"simulator for {self.preset!r} died while starting"
            ) from None
        if status != "ready":
            self.stop()
            raise SimulatorProcessError(f"simulator for {self.preset!r} failed: {payload}")
        for name, info in payload.items():
            self.arms[name] = RemoteArm(
                self, name, info["port"], info["motors"], info["calibration"]
            )
        return self

    def call(self, arm: str, method: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> Any:
        if self._conn is None:
            raise SimulatorProcessError("simulator process is not running; call start() first")
        with self._lock:
            try:
                self._conn.send((arm, method, args, kwargs))
                status, payload = self._conn.recv()
            except (EOFError, OSError) as exc:
                raise SimulatorProcessError("simulator process died") from exc
        if status == "error":
            raise payload
        return payload

    def stop(self) -> None:
        conn, process = self._conn, self._process
        self._conn = self._process = None
        self.arms = {}
        if conn is not None:
            try:
                conn.send(None)
            except OSError:
                pass
            conn.close()
        if process is not None:
            process.join(timeout=5)
            if process.is_alive():
                process.terminate()
                process.join(timeout=5)



def _child_main(
    conn: multiprocessing.connection.Connection, preset: str, options: dict[str, Any]
) -> None:
    """Child entry point: serve the cell until the parent says stop or goes away."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when we stop
    from .presets import build_cell
    from .pty_server import interleave_serving_threads

    interleave_serving_threads()

    try:
        cell = build_cell(preset, **options).start()
    except Exception as exc:  # noqa: BLE001 - reported to the parent, which raises
        conn.send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    try:
        conn.send(
            (
                "ready",
                {
                    name: {"port": arm.port, "motors": arm.motors, "calibration": arm.calibration}
                    for name, arm in cell.arms.items()
                },
            )
        )
        while True:
            try:
                request = conn.recv()
            except EOFError:
                return
            if request is None:
                return
            arm_name, method, args, kwargs = request
            try:
                if method not in REMOTE_METHODS:
                    raise AttributeError(f"{method!r} cannot be called remotely")
                result = getattr(cell.arms[arm_name], method)(*args, **kwargs)
                conn.send(("ok", result))
            except Exception as exc:  # noqa: BLE001 - the caller gets the exception
                conn.send(("error", exc))
    finally:
        cell.stop()
