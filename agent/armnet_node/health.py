"""A cell's health conditions from what the probes found. Pure.

The operator binds only to cells with no health condition ``False``; each
false condition says what is wrong and what the person at the cell should do.
The probes (``node.probes``) gather the facts; while a job holds the bus they
do not touch it, and the hardware facts come from the last idle probe and the
connector (interlock) instead. Whether the cell's devices are there at all is
the device watch's verdict (``node.device_health``), the one the device plugin
reports to the kubelet too: it comes first in ``HardwareReady``, job or not.

The condition types are the API's (``armnet_core.api``, the operator reads the same
names); ``merge_conditions`` is the core's (``armnet_core.conditions``), the rule the
operator writes its own conditions by.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from armnet_core.api import AUTO_RESET_CONDITION as AUTO_RESET_WORKING
from armnet_core.api import STREAMS_CONNECTED_CONDITION as STREAMS_CONNECTED
from armnet_core.api import CellConditionType
from armnet_core.conditions import merge_conditions as merge_conditions

AGENT_CONNECTED = CellConditionType.AGENT_CONNECTED
HARDWARE_READY = CellConditionType.HARDWARE_READY
CALIBRATION_PRESENT = CellConditionType.CALIBRATION_PRESENT
CAMERAS_READY = CellConditionType.CAMERAS_READY
INTERLOCK_CLEAR = CellConditionType.INTERLOCK_CLEAR
COMPLETION_READY = CellConditionType.COMPLETION_READY
HEALTH_CONDITIONS = tuple(CellConditionType)


@dataclass(frozen=True)
class ArmProbe:
    """One arm's bus: what each expected servo answered on its port (its presence is the device watch's)."""

    port: str
    #: motor name -> (servo id, model number it answered with, or None if silent)
    answers: Mapping[str, tuple[int, int | None]] = field(default_factory=dict)
    expected_model: int = 777
    calibration_file: str | None = None
    calibration_exists: bool = False
    calibration_missing: tuple[str, ...] = ()
    calibration_error: str | None = None
    #: Servo registers whose EEPROM value differs from the cell's calibration file, as
    #: "<motor> <register> holds <read>, the cell's file says <expected>" (empty: all match
    #: or not read). A job cannot cause this (the register policy refuses calibration
    #: writes); someone changed the servo outside armnet, or it was replaced.
    calibration_mismatches: tuple[str, ...] = ()


@dataclass(frozen=True)
class CellProbe:
    arms: Mapping[str, ArmProbe]
    #: camera name -> None if a frame was read, else the error
    cameras: Mapping[str, str | None] = field(default_factory=dict)
    #: the connector's interlock trip message while a job runs, None when clear
    interlock_trip: str | None = None
    #: a job holds the bus: the hardware facts are the last idle probe's
    bus_held_by_job: bool = False
    #: (reason, message) when the device watch finds the cell's devices lost (``device_health``)
    devices_lost: tuple[str, str] | None = None


@dataclass(frozen=True)
class StreamsProbe:
    """The agent's NATS link as the heartbeat finds it."""

    #: A NATS URL is configured (flag, ARMNET_AGENT_NATS_URL or NATS_URL).
    configured: bool
    #: Connected, with the log stream in place.
    connected: bool = False
    #: ``host:port`` of the server, for the message (never the URL: it may carry a password).
    server: str = ""


@dataclass(frozen=True)
class Condition:
    type: str
    status: str
    reason: str
    message: str


def _ok(kind: str, reason: str, message: str) -> Condition:
    return Condition(kind, "True", reason, message)


def _bad(kind: str, reason: str, message: str) -> Condition:
    return Condition(kind, "False", reason, message)


def cell_health(probe: CellProbe) -> tuple[Condition, ...]:
    """The five health conditions of a cell whose agent is alive (AgentConnected is True)."""
    return (
        _ok(AGENT_CONNECTED, "Heartbeat", "the node agent is running and renewing the heartbeat"),
        hardware_condition(probe),
        calibration_condition(probe),
        cameras_condition(probe),
        interlock_condition(probe),
    )


def hardware_condition(probe: CellProbe) -> Condition:
    if probe.devices_lost is not None:
        return _bad(HARDWARE_READY, *probe.devices_lost)
    for name, arm in sorted(probe.arms.items()):
        silent = [f"{motor} (id {sid})" for motor, (sid, model) in sorted(arm.answers.items()) if model is None]
        if silent:
            return _bad(
                HARDWARE_READY, "ServoNotResponding",
                f"arm {name}: servo(s) {', '.join(silent)} do not answer a ping on {arm.port}; "
                "check the servo cables and the power supply",
            )
        wrong = [
            f"{motor} (id {sid}) is model {model}"
            for motor, (sid, model) in sorted(arm.answers.items())
            if model is not None and model != arm.expected_model
        ]
        if wrong:
            return _bad(
                HARDWARE_READY, "WrongServoModel",
                f"arm {name}: expected model {arm.expected_model} on every joint, but {', '.join(wrong)}; "
                "replace the servo or fix its id",
            )
    detail = " (last checked before the running job took the bus)" if probe.bus_held_by_job else ""
    return _ok(HARDWARE_READY, "AllServosAnswer", f"every configured servo answers with the expected model{detail}")


def calibration_condition(probe: CellProbe) -> Condition:
    for name, arm in sorted(probe.arms.items()):
        if arm.calibration_file is None:
            return _bad(
                CALIBRATION_PRESENT, "NoCalibrationConfigured",
                f"arm {name}: no calibration file configured; set robotId and calibrationDir on the Cell",
            )
        if not arm.calibration_exists:
            return _bad(
                CALIBRATION_PRESENT, "CalibrationMissing",
                f"arm {name}: {arm.calibration_file} does not exist; run lerobot-calibrate for this arm",
            )
        if arm.calibration_error is not None:
            return _bad(
                CALIBRATION_PRESENT, "CalibrationInvalid",
                f"arm {name}: {arm.calibration_error}; re-run lerobot-calibrate for this arm",
            )
        if arm.calibration_missing:
            return _bad(
                CALIBRATION_PRESENT, "CalibrationIncomplete",
                f"arm {name}: {arm.calibration_file} has no entry for {', '.join(arm.calibration_missing)}; "
                "re-run lerobot-calibrate for this arm",
            )
        if arm.calibration_mismatches:
            shown = "; ".join(arm.calibration_mismatches[:4])
            more = f" (and {len(arm.calibration_mismatches) - 4} more)" if len(arm.calibration_mismatches) > 4 else ""
            return _bad(
                CALIBRATION_PRESENT, "CalibrationMismatch",
                f"arm {name}: the servos' EEPROM differs from {arm.calibration_file}: {shown}{more}; "
                "re-run lerobot-calibrate for this arm (and replace the file), or restore the servos' calibration",
            )
    return _ok(CALIBRATION_PRESENT, "CalibrationFound", "every arm has a calibration covering all its motors")


def cameras_condition(probe: CellProbe) -> Condition:
    failed = {name: error for name, error in sorted(probe.cameras.items()) if error is not None}
    if failed:
        listed = "; ".join(f"{name}: {error}" for name, error in failed.items())
        return _bad(CAMERAS_READY, "CameraUnreadable", f"no frame from camera(s) {listed}; check the camera cable")
    return _ok(CAMERAS_READY, "FramesRead", f"{len(probe.cameras)} camera(s) deliver frames")


def interlock_condition(probe: CellProbe) -> Condition:
    if probe.interlock_trip is not None:
        return _bad(
            INTERLOCK_CLEAR, "InterlockTripped",
            f"the running job's interlock is tripped: {probe.interlock_trip}; it clears when the job ends",
        )
    return _ok(INTERLOCK_CLEAR, "Clear", "motion is allowed")


def completion_condition(problem: str | None, reason: str = "FileUnusable") -> Condition:
    """``CompletionReady`` on a cell whose completion monitor reads files on the robot host (a classifier's
    model, a judge's token file): ``problem`` is why it cannot use them (``completion_model.files_problem``),
    None when it can.

    A health condition: a cell whose monitor cannot score would run every evaluation to
    "not complete", so it is not bound until the file is fixed. ``reason``: ``FileUnusable``,
    or ``CannotSeeTheArm`` (``MONITOR_SEES_NO_ARM``).
    """
    if problem is None:
        return _ok(COMPLETION_READY, "FilesUsable", "the completion monitor's files on this host load and answer")
    return _bad(COMPLETION_READY, reason,
                f"{problem[:900]}; no job is bound to this cell until its completion monitor can score")


MONITOR_SEES_NO_ARM = (
    "this node agent runs the cell simulator itself (--pod-simulator agent), so a job pod's simulated camera "
    "draws no arm and the completion monitor could never see the task done; run the agent with "
    "--pod-simulator sidecar (the Helm chart's agent.podSimulator) for simulated cells with spec.completion"
)


INPUTS_NEED_NATS = ("the cell operator's Confirm reset and Success/Fail, teleop and live logs "
                    "reach this cell's jobs only through it")


def streams_condition(probe: StreamsProbe) -> Condition:
    """``StreamsConnected``: whether the operator's inputs can reach this cell's jobs at all."""
    if not probe.configured:
        return _bad(
            STREAMS_CONNECTED, "NatsNotConfigured",
            f"the node agent has no NATS server; {INPUTS_NEED_NATS}, so a job waiting for a reset waits out "
            "its timeout: give the agent --nats-url, ARMNET_AGENT_NATS_URL or NATS_URL",
        )
    if not probe.connected:
        return _bad(
            STREAMS_CONNECTED, "NatsUnreachable",
            f"the node agent cannot reach NATS at {probe.server or 'its URL'} (it keeps retrying); "
            f"{INPUTS_NEED_NATS}: check the server and the agent's URL and credentials",
        )
    return _ok(STREAMS_CONNECTED, "Connected", f"the node agent's NATS link to {probe.server} is up")


def auto_reset_condition(latest: Mapping[str, Any] | None) -> Condition:
    """``AutoResetWorking`` on a cell with a scripted reset: whether the latest one worked without a person.

    Not a health condition (the operator still binds: a person can reset the cell), so it
    is False only to tell the person at the cell and the platform team. ``latest`` is the
    connector's report of it (``AutoResetReport.as_status()``); a reset the interlock
    stopped says nothing about the workspace and is not passed here.
    """
    if latest is None:
        return _ok(AUTO_RESET_WORKING, "NoResetYet", "no scripted reset has run on this cell since the node agent started")
    message = str(latest.get("message") or "")[:1000]
    if latest.get("outcome") == "fell_back":
        return _bad(AUTO_RESET_WORKING, "FellBackToOperator", message)
    return _ok(AUTO_RESET_WORKING, "Worked", message)
