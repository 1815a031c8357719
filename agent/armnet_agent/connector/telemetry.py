"""Servo telemetry and the latest camera frames of a cell, read for the cell operator's page.

Reads only. Servo values come from one ``GroupSyncRead`` of the 8 registers from
``Present_Position`` (56) to ``Present_Temperature`` (63) on every servo of an arm:
one request and one short reply per servo, a few milliseconds at 1 Mbaud. While a job
runs, the read takes the arm's device lock like every job call does, with a short
wait: when the job's call holds the device, this tick is skipped rather than making
the job wait, so a job's bus loop waits at most for one such read per tick. The read
uses the job's own connected bus when it has one (no second handle on the port),
else a port handle of the connector's own, closed at once.

Frames are the job's camera objects' latest captures (the same picture the job
sees); nothing here opens a camera a job may open.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .cell import CellState

log = logging.getLogger(__name__)

TELEMETRY_START = 56
"""``Present_Position`` on the STS3215; the block runs through ``Present_Temperature`` (63)."""
TELEMETRY_LENGTH = 8
BAUD_RATE = 1_000_000
LOCK_WAIT_S = 0.02
"""How long a telemetry read waits for a device a job call holds before skipping this tick."""


@dataclass(frozen=True)
class ServoSample:
    """One servo's raw readings: position in ticks, load in 0.1 % of the rated torque (signed), °C."""

    position: int
    load: int
    temperature: int


def _sign_magnitude(value: int, sign_bit: int) -> int:
    magnitude = value & ((1 << sign_bit) - 1)
    return -magnitude if value & (1 << sign_bit) else magnitude


def decode_block(block: bytes | list[int]) -> ServoSample:
    """The sample in one servo's 8-byte telemetry block (little-endian, Feetech sign-magnitude). Pure."""
    data = bytes(block)
    if len(data) < TELEMETRY_LENGTH:
        raise ValueError(f"a telemetry block has {TELEMETRY_LENGTH} bytes, got {len(data)}")
    position = _sign_magnitude(int.from_bytes(data[0:2], "little"), 15)
    load = _sign_magnitude(int.from_bytes(data[4:6], "little"), 10)
    return ServoSample(position=position, load=load, temperature=data[7])


def read_block(port_handler: Any, packet_handler: Any, ids: Iterable[int]) -> dict[int, ServoSample | None]:
    """Servo id -> its sample (None: it did not answer), from one sync read on an open port."""
    from scservo_sdk import GroupSyncRead

    wanted = sorted(set(ids))
    group = GroupSyncRead(port_handler, packet_handler, TELEMETRY_START, TELEMETRY_LENGTH)
    for sid in wanted:
        group.addParam(sid)
    try:
        group.txRxPacket()  # stops at the first silent servo; those before it still hold their data
    except (IndexError, OSError) as exc:  # scservo_sdk raises IndexError on a cut-short reply
        log.debug("telemetry sync read failed: %s", exc)
    samples: dict[int, ServoSample | None] = {}
    for sid in wanted:
        raw = group.data_dict.get(sid) or []
        samples[sid] = decode_block(raw) if len(raw) >= TELEMETRY_LENGTH else None
    return samples


def read_port(port: str, ids: Iterable[int]) -> dict[int, ServoSample | None]:
    """One sync read on ``port`` through a handle opened and closed here (no job holds the port)."""
    from scservo_sdk import PacketHandler, PortHandler

    handler = PortHandler(port)
    if not handler.openPort():
        raise OSError(f"cannot open {port}")
    try:
        handler.setBaudRate(BAUD_RATE)
        return read_block(handler, PacketHandler(0), ids)
    finally:
        handler.closePort()


def name_samples(
    ids: Mapping[str, int], samples: Mapping[int, ServoSample | None]
) -> dict[str, ServoSample | None]:
    """motor -> sample, for the motors of ``ids`` (motor -> servo id). Pure."""
    return {motor: samples.get(sid) for motor, sid in ids.items()}


def read_cell_servos(cell: CellState, lock_wait_s: float = LOCK_WAIT_S) -> dict[str, dict[str, ServoSample | None] | str]:
    """arm -> (motor -> sample), or why the arm was not read this time (device busy, no calibration, error)."""
    result: dict[str, dict[str, ServoSample | None] | str] = {}
    for arm_name, arm in cell.config.arms.items():
        ranges = cell.ranges.get(arm_name) or {}
        if not ranges:
            result[arm_name] = "no calibration file: its servos' ids are unknown"
            continue
        ids = {motor: r.id for motor, r in ranges.items()}
        lock = cell.locks.get(arm.port)
        if not lock.acquire(lock_wait_s):
            result[arm_name] = "busy"
            continue
        try:
            bus = _job_bus(cell, arm_name)
            if bus is not None:
                samples = read_block(bus.port_handler, bus.packet_handler, ids.values())
            else:
                samples = read_port(arm.port, ids.values())
            result[arm_name] = name_samples(ids, samples)
        except Exception as exc:  # noqa: BLE001 - telemetry is best effort; the job's own calls report the bus
            result[arm_name] = f"{type(exc).__name__}: {str(exc)[:200]}"
        finally:
            lock.release()
    return result


def _job_bus(cell: CellState, arm_name: str) -> Any:
    for handle in cell.live_handles():
        if handle.class_name == "FeetechMotorsBus" and handle.arm == arm_name and handle.obj.is_connected:
            return handle.obj
    return None


@dataclass(frozen=True)
class CameraFrame:
    """A camera's newest picture (an HxWx3 uint8 array) and its colour order."""

    image: Any
    bgr: bool = False


def latest_frames(cell: CellState) -> dict[str, CameraFrame]:
    """Camera name -> the newest frame of each camera the job opened (a copy: the job keeps its own)."""
    frames: dict[str, CameraFrame] = {}
    for handle in cell.live_handles():
        if handle.class_name != "OpenCVCamera":
            continue
        name = handle.lock.name.removeprefix("camera:")
        lock = getattr(handle.obj, "frame_lock", None)
        if lock is None:
            continue
        with lock:
            frame = getattr(handle.obj, "latest_frame", None)
        if frame is not None:
            mode = getattr(getattr(handle.obj, "color_mode", None), "value", getattr(handle.obj, "color_mode", ""))
            frames[name] = CameraFrame(frame.copy(), bgr=str(mode).lower() == "bgr")
    return frames
