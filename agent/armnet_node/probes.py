"""Gathers a cell's health facts from the hardware (or its simulator) while no job holds the bus.

Each arm's bus is pinged with the real ``scservo_sdk`` (the simulator answers
on a pty exactly as servos answer on a USB adapter); the calibration file is
read and checked against the arm's motors. While a job runs the connector owns
the bus: the worker does not call :func:`probe_arm` then, and asks the
connector for its interlock instead (``node.health`` turns the facts into
conditions). Nor does it probe while the device watch finds a device missing
(``node.device_watch``): whether a port exists is the watch's to say.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from functools import partial
from pathlib import Path
from typing import Any

from armnet_connector.block_read import ask_until_answered
from armnet_connector.calibration_check import (
    READ_RETRIES,
    calibration_mismatches,
    read_calibration,
)
from armnet_connector.config import MotorRange, read_calibration_file
from armnet_connector.reply_window import use_lerobot_reply_window

from armnet_node.health import ArmProbe

log = logging.getLogger(__name__)

BAUD_RATE = 1_000_000
#: Pings per servo before it counts as silent, with LeRobot's reply window and a wait for a
#: late reply before each retry, as the calibration read asks: a loaded host's simulator (or
#: a busy robot host) misses a reply now and then, and a healthy servo must not read silent.
PING_TRIES = 1 + READ_RETRIES
#: Once a servo stayed silent through every try the bus is most likely unpowered or unplugged:
#: the others are asked this often, so a dead arm's probe stays short (the heartbeat waits).
PING_TRIES_AFTER_SILENCE = 2
STS3215_MODEL = 777
SO101_MOTOR_NAMES = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")


def probe_arm(port: str, calibration_file: Path | None, motors: Iterable[str] = SO101_MOTOR_NAMES) -> ArmProbe:
    motors = tuple(motors)
    calibration_exists = calibration_file is not None and calibration_file.is_file()
    ids: dict[str, int] = {}
    ranges: dict[str, MotorRange] = {}
    missing: tuple[str, ...] = ()
    error = None
    if calibration_file is not None and calibration_exists:
        try:
            ranges = read_calibration_file(calibration_file)
            ids = {motor: r.id for motor, r in ranges.items()}
            missing = tuple(m for m in motors if m not in ranges)
        except (OSError, ValueError) as exc:
            error = str(exc)
    if not ids:
        ids = {motor: index + 1 for index, motor in enumerate(motors)}  # the SO-101's factory ids
    answers = ping_servos(port, ids)
    everyone_answered = bool(answers) and all(model == STS3215_MODEL for _id, model in answers.values())
    mismatches = eeprom_mismatches(port, ranges) if everyone_answered and ranges and not missing else ()
    return ArmProbe(
        port=port,
        answers=answers,
        expected_model=STS3215_MODEL,
        calibration_file=str(calibration_file) if calibration_file is not None else None,
        calibration_exists=calibration_exists,
        calibration_missing=missing,
        calibration_error=error,
        calibration_mismatches=mismatches,
    )


def eeprom_mismatches(port: str, ranges: Mapping[str, MotorRange]) -> tuple[str, ...]:
    """The calibration registers whose EEPROM value is not the cell's file's, as readable lines.

    Read through the connector's own check (plain ``scservo_sdk`` reads, no LeRobot). A read
    that fails says nothing here: HardwareReady already reports servos that do not answer.
    """
    expected = {r.id: (r.homing_offset, r.range_min, r.range_max) for r in ranges.values()}
    names = {r.id: name for name, r in ranges.items()}
    try:
        held = read_calibration(port, expected, baudrate=BAUD_RATE)
    except Exception as exc:  # noqa: BLE001 - a probe never fails the heartbeat; pings report the bus
        log.debug("calibration read on %s failed: %s", port, exc)
        return ()
    return tuple(
        f"{names.get(m.motor_id, m.motor_id)} {m.register} holds {'nothing' if m.read is None else m.read}, "
        f"the cell's file says {m.expected}"
        for m in calibration_mismatches(expected, held)
        if m.read is not None
    )


def ping_servos(port: str, ids: dict[str, int]) -> dict[str, tuple[int, int | None]]:
    """motor -> (id, model number or None when the servo stays silent)."""
    from scservo_sdk import COMM_SUCCESS, PacketHandler, PortHandler
    from serial import SerialException

    handler = PortHandler(port)
    silent: dict[str, tuple[int, int | None]] = {motor: (sid, None) for motor, sid in ids.items()}
    try:
        opened = handler.openPort()
    except (SerialException, OSError) as exc:  # the device vanished since the device watch's read
        log.debug("opening %s failed: %s", port, exc)
        return silent
    if not opened:
        return silent
    try:
        handler.setBaudRate(BAUD_RATE)
        use_lerobot_reply_window(handler)
        packets = PacketHandler(0)
        answers: dict[str, tuple[int, int | None]] = {}
        tries = PING_TRIES
        for motor, sid in sorted(ids.items(), key=lambda item: item[1]):
            model = ask_until_answered(handler, partial(_ping, packets, handler, sid, COMM_SUCCESS), tries)
            if model is None:
                tries = PING_TRIES_AFTER_SILENCE
            answers[motor] = (sid, model)
        return answers
    finally:
        handler.closePort()


def _ping(packets: Any, handler: Any, sid: int, success: int) -> int | None:
    """The model number, or None when the servo is silent or its reply is cut short.

    ``scservo_sdk`` raises IndexError on a truncated reply instead of reporting it.
    """
    try:
        model, result, _error = packets.ping(handler, sid)
    except (IndexError, OSError):
        return None
    return int(model) if result == success else None
