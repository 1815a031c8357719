"""The state one connector shares between its connections: the cell of one job.

This module owns the shared facts (config, interlock, deadline, inputs, the
live objects of every connection, counters, each arm's register ledger) and the
cell-wide actions (``return_to_rest``, ``reset`` with its scripted tries and
fallback to a person, releasing every device and putting back the registers a
job changed). Per-connection request handling lives
in ``session``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from .auto_reset import (
    FELL_BACK,
    STOPPED,
    WORKED,
    AttemptReport,
    AutoResetReport,
    PoseMover,
    pose_targets,
    step_limits,
)
from .camera_video import CameraVideo
from .config import ConnectorConfig, MotorRange, read_calibration_file
from .deadline import Deadline
from .errors import RequestError, bounded
from .hardware import (
    CameraFactory,
    DeviceLocks,
    Handle,
    cell_motors_of,
    create_feetech,
    opencv_camera_factory,
    simulated_camera_factory,
)
from .inputs import CompletionMonitor, NeverComplete, OperatorInputs
from .interlock import Interlock, TripReason
from .motion import MotionGuard
from .rest import RestReport, cell_bus, move_to_rest, rest_pose, restore_registers, torque_off
from .restore import RegisterLedger, RestoreOutcome, restore_block
from .retry import with_read_retry
from .rollout_frames import RolloutFrames
from .servo_trace import ServoTrace

log = logging.getLogger(__name__)


@dataclass
class Counters:
    """Plain counters, exported as metrics later."""

    connections: int = 0
    requests: int = 0
    errors: int = 0
    safety_violations: int = 0
    objects_created: int = 0
    resets: int = 0
    #: Bus reads repeated after a lost servo reply (see ``retry``).
    bus_retries: int = 0
    #: Connections turned away at the per-socket cap or when no thread could serve them.
    connections_refused: int = 0
    #: ``accept`` failures (e.g. at the file-descriptor limit); the socket keeps serving.
    accept_errors: int = 0
    #: Connections closed for a request line over the line cap or the connector's buffer cap.
    oversized_requests: int = 0
    #: Calls whose retry count or timeout was lowered to the connector's cap (``buscaps``).
    calls_capped: int = 0
    #: Returns to rest that ended outside their tolerance, or could not be made.
    rests_missed: int = 0
    #: Torque offs the connector could not confirm by reading the servos back.
    torque_off_unconfirmed: int = 0
    #: Stops that found a device still busy past the wait and turned torque off beside the call.
    stop_lock_timeouts: int = 0
    #: Registers a job changed that the connector wrote back and read back as the job found them.
    registers_restored: int = 0
    #: Restores that left a register as the job changed it (alert: the next tenant would inherit it).
    register_restore_failures: int = 0
    #: Frames the completion monitor scored (``completion``).
    completion_frames_scored: int = 0
    #: Scores that raised: each counts as "not complete" (alert: the cell's scorer is broken).
    completion_scorer_errors: int = 0
    #: Scores slower than the monitor's limit: each counts as "not complete".
    completion_scorer_slow: int = 0
    #: Times the monitor's camera could not be opened or stopped delivering frames.
    completion_camera_errors: int = 0
    #: ``is_complete(block=True)`` calls that saw no frame newer than the call scored in time.
    completion_block_timeouts: int = 0
    #: Pictures of rollouts (first, verdict, last) kept in the cell's record of the job (``rollout_frames``).
    rollout_frames_kept: int = 0
    #: Pictures not kept: the writer was behind, the job ran past the cap of rollouts, or a write failed.
    rollout_frames_dropped: int = 0
    #: Rows of the cell's servo trace written to its record of the job (``servo_trace``).
    trace_rows_written: int = 0
    #: Rows not kept: the writer was behind, or a part could not be written.
    trace_rows_dropped: int = 0
    #: Camera frames encoded into the cell's video of the job (``camera_video``; at most its rate).
    video_frames_written: int = 0
    #: Frames not kept: the encoder was behind, a frame was no picture, or the encoder failed.
    video_frames_dropped: int = 0
    #: Scripted resets the completion monitor judged back at their start (no person involved).
    auto_resets_worked: int = 0
    #: Tries of a scripted reset that failed (moves not made, or the scene still scored complete).
    auto_reset_attempts_failed: int = 0
    #: Scripted resets that ran out of tries and asked the person at the cell (alert: look at the workspace).
    auto_resets_fell_back: int = 0
    #: Scripted resets the interlock stopped (a safety refusal, the deadline's grace window, the stop).
    auto_resets_stopped: int = 0


@dataclass(frozen=True)
class RolloutEvent:
    kind: str  # "begin" | "end" | "verdict" (the completion monitor's, on the open rollout)
    at: float
    index: int | None = None
    total: int | None = None
    outcome_controls: bool | None = None
    #: A verdict's outcome, score and the wall-clock time its newest frame was scored.
    success: bool | None = None
    score: float | None = None
    frame_at: float | None = None


MAX_ROLLOUT_EVENTS = 1024
#: Scripted resets kept with their tries (``CellState.auto_resets``); the counters count them all.
MAX_AUTO_RESETS_KEPT = 64
#: A scripted reset's judgement waits for this many scoring periods per frame it needs, plus ``BLOCK``'s second.
JUDGE_PERIODS_PER_FRAME = 3.0


@dataclass
class CellState:
    config: ConnectorConfig
    inputs: OperatorInputs
    completion: CompletionMonitor = field(default_factory=NeverComplete)
    camera_factory: CameraFactory | None = None
    on_grace_expired: Callable[[], None] | None = None
    interlock: Interlock = field(default_factory=Interlock)
    locks: DeviceLocks = field(default_factory=DeviceLocks)
    counters: Counters = field(default_factory=Counters)
    # The latest rollout events only: a job may begin millions of rollouts.
    rollouts: deque[RolloutEvent] = field(default_factory=lambda: deque(maxlen=MAX_ROLLOUT_EVENTS))
    #: The rollouts' pictures in the cell's record of the job (a cell with a monitor and a record directory).
    rollout_frames: RolloutFrames | None = None
    #: The cell's servo trace and camera video of the job (a host that gives a record directory).
    servo_trace: ServoTrace | None = None
    camera_video: CameraVideo | None = None

    def __post_init__(self) -> None:
        self.ranges: dict[str, dict[str, MotorRange]] = {
            name: read_calibration_file(arm.calibration_file) if arm.calibration_file else {}
            for name, arm in self.config.arms.items()
        }
        if self.camera_factory is None:
            self.camera_factory = simulated_camera_factory() if self.config.simulated else opencv_camera_factory
        self.deadline = Deadline(
            self.config.timeout_seconds, self.config.grace_period_seconds, self.interlock, self.on_grace_expired
        )
        self.guard = MotionGuard(
            self.interlock, self.config.present_position_max_age_ms / 1000, self.counters,
            policy=self.config.safety_policy,
        )
        self._live: dict[int, Handle] = {}
        #: The latest return to rest of each arm, as read back from its servos.
        self.rest_reports: dict[str, RestReport] = {}
        #: Per arm: whether the latest torque off was read back as off.
        self.torque_confirmed: dict[str, bool] = {}
        #: Set when the job ends: connections closing then leave rest and torque off to ``shut_down``.
        self.stopping = threading.Event()
        #: Per arm: the values the job found in the registers it may tune (``restore``).
        self.ledgers: dict[str, RegisterLedger] = {name: RegisterLedger() for name in self.config.arms}
        self._live_lock = threading.Lock()
        self._reset_lock = threading.Lock()
        #: One verdict per rollout: the check and the append happen together.
        self._rollout_lock = threading.Lock()
        #: Why the job is to stop at the end of the open rollout (``stop_at_episode_end``), until that end.
        self._stop_at_end: str | None = None
        #: The latest scripted resets (``reset``), oldest first.
        self.auto_resets: deque[AutoResetReport] = deque(maxlen=MAX_AUTO_RESETS_KEPT)
        #: The scripted reset's poses as arm -> raw goals, or why the cell's calibration rules them out.
        self.reset_targets: list[dict[str, dict[str, int]]] = []
        self.reset_unusable: str | None = None
        reset = self.config.reset
        if reset is not None and reset.scripted:
            motors = {name: cell_motors_of(arm, self.ranges[name]) for name, arm in self.config.arms.items()}
            try:
                self.reset_targets = pose_targets(reset.poses, self.ranges, motors)
            except ValueError as exc:
                self.reset_unusable = str(exc)
                log.error("the cell's scripted reset cannot run, every reset asks the person at the cell: %s", exc)

    # -- the live objects of every connection ---------------------------------------

    def register(self, handle: Handle) -> None:
        with self._live_lock:
            self._live[id(handle)] = handle
        self.counters.objects_created += 1

    def unregister(self, handle: Handle) -> None:
        with self._live_lock:
            self._live.pop(id(handle), None)

    def live_handles(self) -> list[Handle]:
        with self._live_lock:
            return list(self._live.values())

    def release(self, handle: Handle, *, lock_wait_s: float | None = None, torque_off: bool = True) -> None:
        """Disconnect ``handle``'s device if it is connected; never raises (logs instead).

        A bus is disconnected without torque off: several handles of the job may
        drive one arm, and closing one must not drop the arm under the others.
        When the job's last live bus on the arm goes, torque goes off through the
        cell's own bus (``torque_off_arm``), then the registers the job changed go
        back (``restore_arm``). ``lock_wait_s`` bounds the wait for the device (the
        connector's stop); past it the device is left to its call (and the restore to the stop).
        """
        self.unregister(handle)
        lock = handle.lock
        if not lock.acquire(lock.wait_s if lock_wait_s is None else lock_wait_s):
            log.warning("%s is still busy with a call; left to it (its connection is closed)", handle.class_name)
            return
        try:
            if handle.obj.is_connected:
                if handle.class_name == "FeetechMotorsBus":
                    handle.obj.disconnect(disable_torque=False)
                else:
                    handle.obj.disconnect()
        except Exception as exc:  # noqa: BLE001 — a dead device must not stop the others from being released
            log.warning("could not disconnect %s cleanly: %s: %s", handle.class_name, type(exc).__name__,
                        bounded(str(exc)))
        finally:
            lock.release()
        if handle.class_name == "FeetechMotorsBus" and handle.arm is not None and not self._arm_in_use(handle.arm):
            if self.stopping.is_set():
                return  # shut_down releases every arm in its own order
            if torque_off and self.config.disable_torque_on_shutdown:
                self.torque_off_arm(handle.arm, lock_wait_s=lock_wait_s)
            self.restore_arm(handle.arm, lock_wait_s=lock_wait_s)

    def bus_let_go(self, handle: Handle) -> None:
        """A job's own ``disconnect`` of ``handle``: if that was its last connected bus on the arm, restore it.

        Torque is as the job's ``disconnect`` left it (LeRobot's meaning of its
        ``disable_torque``); the registers the job changed go back either way.
        """
        arm = handle.arm
        if arm is None or self.stopping.is_set() or handle.obj.is_connected or self._arm_in_use(arm):
            return
        self.restore_arm(arm)

    def _arm_in_use(self, arm: str) -> bool:
        """Whether another connected bus of the job is on ``arm`` (then its torque stays)."""
        return any(
            h.arm == arm and h.class_name == "FeetechMotorsBus" and h.obj.is_connected for h in self.live_handles()
        )

    def torque_off_arm(self, arm_name: str, *, lock_wait_s: float | None = None) -> bool:
        """Torque off every servo of ``arm_name`` through the cell's own bus; True once read back off.

        Under the device lock when it comes within ``lock_wait_s``; otherwise
        beside the call that holds it (a lone sync write): torque off is the one
        thing that must reach the arm whatever a job's call is doing.
        """
        arm = self.config.arms[arm_name]
        ranges = self.ranges.get(arm_name) or {}
        if not ranges:
            log.warning("arm %s has no calibration file: the connector cannot address its servos", arm_name)
            self.counters.torque_off_unconfirmed += 1
            self.torque_confirmed[arm_name] = False
            return False
        lock = self.locks.get(arm.port)
        locked = lock.acquire(lock.wait_s if lock_wait_s is None else lock_wait_s)
        if not locked:
            self.counters.stop_lock_timeouts += 1
            log.warning("arm %s: its device is still busy; turning torque off beside the call", arm_name)
        try:
            with cell_bus(arm, ranges, handshake=False) as bus:
                confirmed = torque_off(bus)
        except Exception as exc:  # noqa: BLE001 — logged and counted: the record says torque off was not confirmed
            log.error("arm %s: torque off failed: %s: %s", arm_name, type(exc).__name__, bounded(str(exc)))
            confirmed = False
        finally:
            if locked:
                lock.release()
        self.torque_confirmed[arm_name] = confirmed
        if confirmed:
            log.info("arm %s: torque off, read back from its servos", arm_name)
        else:
            self.counters.torque_off_unconfirmed += 1
            log.error("arm %s: torque off was not confirmed by its servos", arm_name)
        return confirmed

    def shut_down(self, lock_wait_s: float, rest_deadline: float | None = None) -> None:
        """The job's end: release every device, rest every arm and torque it off (each if configured),
        and put back the registers the job changed (before the rest, else after torque off).

        A rest still walking at ``rest_deadline`` (``time.monotonic()``) stops there and
        is reported as missed: torque off comes after it and must fit in the grace window.
        """
        for handle in self.live_handles():
            self.release(handle, lock_wait_s=lock_wait_s, torque_off=False)
        if self.config.rest_on_shutdown:
            for arm_name in self.config.arms:
                # First the registers: the walk must move with the cell's torque limit and speed, not the job's.
                self.restore_arm(arm_name, lock_wait_s=lock_wait_s, deadline=rest_deadline)
                try:
                    self._rest_arm(arm_name, lock_wait_s=lock_wait_s, deadline=rest_deadline)
                except RequestError as exc:  # the device is still busy: torque off below goes beside it
                    log.warning("arm %s: no rest at shutdown: %s", arm_name, exc.message)
        if self.config.disable_torque_on_shutdown:
            for arm_name in self.config.arms:
                self.torque_off_arm(arm_name, lock_wait_s=lock_wait_s)
        for arm_name in self.config.arms:  # what is still to put back (all of it, without a rest)
            self.restore_arm(arm_name, lock_wait_s=lock_wait_s, deadline=rest_deadline)

    def ledger(self, arm_name: str) -> RegisterLedger:
        """Where the job's buses on ``arm_name`` note the values they change."""
        return self.ledgers[arm_name]

    def restore_arm(
        self, arm_name: str, *, lock_wait_s: float | None = None, deadline: float | None = None
    ) -> RestoreOutcome | None:
        """Put back every register of ``arm_name`` the job changed, through the cell's own bus; never raises.

        Under the device lock (a job's bus on the device sends nothing meanwhile),
        whatever the interlock says: these are the connector's writes, of values the
        arm held before the job. The outcome goes to the safety report; a register
        still as the job left it stays pending, so a later release or the stop tries
        again. None: nothing was pending.
        """
        ledger = self.ledgers.get(arm_name)
        pending = ledger.pending() if ledger is not None else {}
        if ledger is None or not any(pending.values()):
            return None
        arm = self.config.arms[arm_name]
        ranges = self.ranges.get(arm_name) or {}
        names = {r.id: motor for motor, r in ranges.items()}
        lock = self.locks.get(arm.port)
        wait_s = lock.wait_s if lock_wait_s is None else lock_wait_s
        if deadline is not None:
            wait_s = max(0.0, min(wait_s, deadline - time.monotonic()))
        if not lock.acquire(wait_s):
            outcome = RestoreOutcome(failures=(
                f"the registers the job changed were not written back ({_listed(pending, names)}): the arm's device "
                "stayed busy with a call",
            ))
        else:
            try:
                with cell_bus(arm, ranges, handshake=False) as bus:
                    model = arm.motor_model
                    block = restore_block(model, bus.model_ctrl_table[model], bus.model_encoding_table.get(model, {}))
                    outcome = restore_registers(bus, block, pending, names, on_lost_reply=self.count_bus_retry,
                                                deadline=deadline)
            except Exception as exc:  # noqa: BLE001 — reported, with the bus's own words
                outcome = RestoreOutcome(failures=(
                    f"the registers the job changed were not written back ({_listed(pending, names)}): "
                    f"{type(exc).__name__}: {bounded(str(exc), 300)}",
                ))
            finally:
                lock.release()
        for servo_id, register in outcome.settled:
            ledger.settle(servo_id, register)
        self.guard.recorder.record_restore(arm_name, outcome)
        self.counters.registers_restored += len(outcome.restored)
        if outcome.failures:
            self.counters.register_restore_failures += 1
            log.error("arm %s: registers not restored: %s", arm_name, "; ".join(outcome.failures))
        elif outcome.restored:
            log.info("arm %s: restored %s", arm_name,
                     ", ".join(f"{r.motor} {r.register}={r.value}" for r in outcome.restored))
        return outcome

    # -- cell-wide actions -------------------------------------------------------------

    def return_to_rest(self) -> None:
        """Walk every arm to its rest pose through the cell's own bus; refuse if one did not get there."""
        refusal = self.interlock.refusal()
        if refusal is not None:
            raise RequestError(*refusal)
        reports = [self._rest_arm(name) for name in self.config.arms]
        missed = [r for r in reports if not r.reached]
        if missed:
            raise RequestError("RestNotReached", "; ".join(r.message() for r in missed))

    def _rest_arm(self, name: str, *, lock_wait_s: float | None = None, deadline: float | None = None) -> RestReport:
        arm = self.config.arms[name]
        ranges = self.ranges.get(name) or {}
        if not ranges:
            report = RestReport(name, False, failure="it has no calibration file, so the connector does not know "
                                "its rest pose")
        else:
            lock = self.locks.get(arm.port)
            wait_s = lock.wait_s if lock_wait_s is None else lock_wait_s
            if deadline is not None:  # the stop's budget: waiting for the device must not eat torque off's time
                wait_s = max(0.0, min(wait_s, deadline - time.monotonic()))
            if not lock.acquire(wait_s):
                raise RequestError("DeviceBusy", f"arm {name!r} is still busy with another call; no rest was made")
            try:
                with cell_bus(arm, ranges) as bus:
                    report = move_to_rest(bus, name, rest_pose(arm, ranges), self.config.rest_speed_ticks_per_second,
                                          deadline=deadline, on_lost_reply=self.count_bus_retry)
            except Exception as exc:  # noqa: BLE001 — reported, with the bus's own words
                report = RestReport(name, False, failure=f"{type(exc).__name__}: {bounded(str(exc), 300)}")
            finally:
                lock.release()
        self.rest_reports[name] = report
        if report.reached:
            log.info("%s", report.message())
        else:
            self.counters.rests_missed += 1
            log.warning("%s", report.message())
        return report

    def reset(self) -> None:
        """Rest pose, then the cell's scripted reset if it has one; if none worked, wait for an operator's
        confirmation; on timeout trip the interlock."""
        with self._reset_lock:
            self.counters.resets += 1
            self.trace_event("reset_begin")
            self.return_to_rest()
            if self.config.reset is not None and self.config.reset.scripted and self._scripted_reset():
                self.trace_event("reset_end", detail="scripted")
                return
            timeout = self.config.reset_timeout_seconds
            if self.inputs.wait_reset_confirmation(timeout):
                log.info("reset confirmed by the operator")
                self.trace_event("reset_end", detail="confirmed by the operator")
                return
            message = f"no operator confirmed the reset within {timeout:g} s"
            self.trace_event("reset_end", detail=message)
            self.interlock.trip(TripReason.RESET_TIMEOUT, message)
            raise RequestError(
                "ResetTimeoutException",
                f"{message}; the cell's interlock is tripped. Finish up (save your data) and return.",
            )

    # -- the scripted reset (docs/connector.md, "Resets without a person") ----------------

    def _scripted_reset(self) -> bool:
        """Drive the arms through the cell's reset poses and let the monitor judge; True once it says reset.

        Up to ``reset.attempts`` tries; each failed one is logged and counted. False: the
        person at the cell confirms instead (the caller waits for it, as for a manual reset).
        Raises ``RequestError`` when the interlock trips meanwhile: no move is sent after it,
        and no person is asked (the job hears why, as from any refused motion).
        """
        reset = self.config.reset
        assert reset is not None
        attempts: list[AttemptReport] = []
        if self.reset_unusable is not None:
            attempts.append(AttemptReport(0, False, self.reset_unusable))
            return self._auto_reset_ends(FELL_BACK, attempts)
        for number in range(1, reset.attempts + 1):
            try:
                missed = self._drive_reset_poses()
                done, detail = (False, missed) if missed is not None else self._judge_reset(reset.settle_seconds)
            except RequestError as exc:
                if self.interlock.tripped:
                    attempts.append(AttemptReport(number, False, exc.message))
                    self._auto_reset_ends(STOPPED, attempts)
                    raise
                done, detail = False, f"a write was refused: {exc.error_type}: {bounded(exc.message, 200)}"
            attempts.append(AttemptReport(number, done, detail))
            if done:
                return self._auto_reset_ends(WORKED, attempts)
            log.warning("scripted reset try %d of %d failed: %s", number, reset.attempts, detail)
        return self._auto_reset_ends(FELL_BACK, attempts)

    def _auto_reset_ends(self, outcome: str, attempts: list[AttemptReport]) -> bool:
        report = AutoResetReport(outcome, tuple(attempts), self.now())
        # A try the interlock stopped is not a failed one (nor is a poses' problem found at start: no try).
        failed = sum(1 for a in attempts if not a.reset and a.number > 0) - (outcome == STOPPED)
        self.counters.auto_reset_attempts_failed += failed
        self.auto_resets.append(report)
        self.guard.recorder.record_auto_reset(report.as_status(), failed_attempts=failed)
        if outcome == WORKED:
            self.counters.auto_resets_worked += 1
            log.info("%s", report.message)
        elif outcome == STOPPED:
            self.counters.auto_resets_stopped += 1
            log.warning("%s", report.message)
        else:
            self.counters.auto_resets_fell_back += 1
            log.error("%s", report.message)
        return outcome == WORKED

    def _drive_reset_poses(self) -> str | None:
        """One pass through the poses, arm by arm, each on a bus of the job's kind; None, or why a pose was missed.

        Raises ``RequestError`` when the guard refuses a write (the interlock holds).
        """
        for number, pose in enumerate(self.reset_targets):
            for arm_name, goal in pose.items():
                self._refuse_if_tripped()
                missed = self._drive_arm(arm_name, goal)
                if missed is not None:
                    return f"pose {number}, arm {arm_name}: {missed}"
        return None

    def _drive_arm(self, arm_name: str, goal: dict[str, int]) -> str | None:
        motors = cell_motors_of(self.config.arms[arm_name], self.ranges[arm_name])
        from lerobot.motors import Motor, MotorNormMode

        handle = create_feetech(
            [], {"port": arm_name, "motors": {m: Motor(c.id, c.model, MotorNormMode(c.norm_mode))
                                              for m, c in motors.items()}},
            self.config, self.locks, self.ranges, interlock=self.interlock, recorder=self.guard.recorder,
            on_lost_reply=self.count_bus_retry, ledger_for=self.ledger,
        )
        arm = self.config.arms[arm_name]
        mover = PoseMover(handle, self.guard.check, self.interlock.refusal,
                          self.config.rest_speed_ticks_per_second, self.count_bus_retry,
                          max_steps=step_limits(arm.safety_limit, motors, self.ranges[arm_name]))
        lock = handle.lock
        # A job's bus on the device sends nothing meanwhile (it waits, then DeviceBusy).
        if not lock.acquire(lock.wait_s):
            return f"its device stayed busy with another call for {lock.wait_s:g} s"
        try:
            try:  # the handshake asked again after a lost reply, as a job's connect is (``retry``)
                with_read_retry(handle, "connect", handle.obj.connect, on_retry=self.count_bus_retry,
                                before_retry=self._refuse_if_tripped)
            except (ConnectionError, RuntimeError) as exc:
                return f"its bus did not connect: {bounded(str(exc), 200)}"
            try:
                return mover.drive(goal)
            except (ConnectionError, TimeoutError) as exc:
                return f"the bus failed: {type(exc).__name__}: {bounded(str(exc), 200)}"
            finally:
                try:  # without torque off: the arm holds the pose, and the job's bus takes over
                    handle.obj.disconnect(disable_torque=False)
                except Exception as exc:  # noqa: BLE001 - a bus that fails to close must not hide the move's outcome
                    log.warning("arm %s: the reset's bus did not close cleanly: %s", arm_name, bounded(str(exc), 200))
        finally:
            lock.release()

    def _refuse_if_tripped(self) -> None:
        refusal = self.interlock.refusal()
        if refusal is not None:
            raise RequestError(*refusal)

    def _judge_reset(self, settle_s: float) -> tuple[bool, str]:
        """Settle, then the monitor's judgement: (the scene is back at its start, what the monitor saw)."""
        until = time.monotonic() + settle_s
        while time.monotonic() < until:
            self._refuse_if_tripped()
            time.sleep(min(0.05, max(0.0, until - time.monotonic())))
        completion = self.config.completion
        frames = completion.consecutive_frames if completion is not None else 1
        rate = completion.rate_hz if completion is not None else 1.0
        judgement = self.completion.judge_reset(frames, frames * JUDGE_PERIODS_PER_FRAME / rate + 1.0)
        if judgement is None:
            return False, "the cell has no completion monitor to judge the scene"
        if judgement.reset:
            return True, f"the completion monitor scored {judgement.scored} fresh frames, none complete"
        if judgement.scored < frames:
            return False, judgement.detail
        return False, (f"the completion monitor still sees the task done in {judgement.hits} of {judgement.scored} "
                       f"fresh frames ({judgement.detail})")

    def count_bus_retry(self) -> None:
        """One servo reply lost and asked again (``retry``), by any of the connector's reads."""
        self.counters.bus_retries += 1

    def inputs_end_recording(self, timeout_s: float) -> bool:
        """A calibration job's ``record_ranges_of_motion`` ends on the operator's reset confirmation or stop.

        Waits up to ``timeout_s`` (the recording's poll period): LeRobot's Enter key,
        from the operator's inputs instead of the connector's stdin.
        """
        if self.inputs.stop_requested():
            return True
        return self.inputs.wait_reset_confirmation(timeout_s)

    def record_rollout(self, event: RolloutEvent) -> None:
        """Append a rollout event; an end with a stop pending (``stop_at_episode_end``) opens the grace window."""
        with self._rollout_lock:
            self.rollouts.append(event)
            why = self._stop_at_end if event.kind == "end" else None
            if why is not None:
                self._stop_at_end = None
                self.deadline.cancel(why)
        self.trace_event(f"rollout_{event.kind}", rollout=event.index,
                         detail=f"of {event.total}" if event.total is not None else None)
        frames = self.rollout_frames
        if frames is not None and event.kind == "begin":
            frames.begun(event.index, event.at)
        elif frames is not None and event.kind == "end":
            frames.ended()
        log.info("rollout %s index=%s total=%s", event.kind, event.index, event.total)
        if why is not None:
            log.info("the episode ended: the stop that waited for it opened the grace window (%s)", why)

    def stop_at_episode_end(self, why: str) -> bool:
        """Open the grace window at the job's next episode boundary; True if it is open on return.

        A preempted job is never stopped mid-episode (docs/connector.md, "Preemption"):
        the window opens when the job ends a rollout (``record_rollout`` of its end),
        the one it is in or, between rollouts, its next one; a job that never began a
        rollout has no episodes to wait for, and its window opens now, as a cancel's
        does (the interlock's reason is ``why``). Not at once between rollouts: the job
        asks ``is_shutting_down()`` right after a rollout ends and then begins the next
        one, and a window opened between its question and its ``rollout_begin`` would
        refuse that rollout's first move. At a rollout's end the window is open before
        the job's ``rollout_end`` returns, so its next question sees it. A second
        request changes nothing (the first ``why`` stands); once the window is open,
        from whatever opened it, this returns True.

        The decision and the opening happen under the rollouts' lock, so no rollout can
        begin between them. That is safe: tripping the interlock takes only the
        interlock's own lock, and nothing holding that lock waits for this one.
        """
        with self._rollout_lock:
            if self.deadline.deadline_passed:
                return True
            if self._stop_at_end is not None:
                return False
            if self._rollout_open() or self._rollouts_seen():
                self._stop_at_end = why
                pending = True
            else:
                self.deadline.cancel(why)
                pending = False
        if pending:
            log.info("stop requested (%s): the grace window opens at the end of the open rollout", why)
        return not pending

    def _rollouts_seen(self) -> bool:
        """Whether the job began a rollout (it runs episodes). Under ``_rollout_lock``."""
        return any(event.kind == "begin" for event in self.rollouts)

    def _rollout_open(self) -> bool:
        """Whether the latest begin or end is a begin (a verdict is neither). Under ``_rollout_lock``."""
        for event in reversed(self.rollouts):
            if event.kind in ("begin", "end"):
                return event.kind == "begin"
        return False

    def record_monitor_verdict(self, *, told_complete: bool) -> None:
        """Record the completion monitor's verdict on the open rollout, once per rollout.

        Called when the monitor told the job "complete" (``told_complete``: the answer the
        job acts on is the verdict, whatever the streak says by now), and at the rollout's
        end (the monitor's last word: complete is a success, anything else a failure).
        Nothing on a cell without a monitor, outside a rollout, or when this rollout
        already has its verdict: the first one the job could act on stands.
        """
        audit = self.completion.audit()
        if audit is None:
            return
        success = told_complete or audit.complete
        with self._rollout_lock:  # the check and the append together; appends take it too
            index = None
            for event in reversed(list(self.rollouts)):
                if event.kind in ("end", "verdict"):
                    return
                if event.kind == "begin":
                    index = event.index
                    break
            if index is None:
                return
            self.rollouts.append(RolloutEvent("verdict", self.now(), index=index, success=success,
                                              score=audit.score, frame_at=audit.frame_at))
        self.trace_event("monitor_verdict", rollout=index, value=audit.score,
                         detail="success" if success else "failure")
        if self.rollout_frames is not None:
            self.rollout_frames.judged()
        log.info("rollout %s: the completion monitor's verdict is %s (score %.3f)", index,
                 "success" if success else "failure", audit.score)

    def trace_event(self, kind: str, **facts: Any) -> None:
        """An event in the cell's servo trace of the job (``servo_trace.ServoTrace.event``), if it keeps one."""
        if self.servo_trace is not None:
            self.servo_trace.event(kind, **facts)

    @staticmethod
    def now() -> float:
        return time.time()


def _listed(pending: dict[int, dict[str, int]], names: dict[int, str]) -> str:
    """``pending`` as "motor Register, ..." for a failure line."""
    return ", ".join(
        f"{names.get(servo_id, f'servo {servo_id}')} {register}"
        for servo_id, registers in sorted(pending.items()) for register in registers
    )
