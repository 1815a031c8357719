"""What a cell's servo readings are, from bytes or from what a job already read. Pure.

Two sources feed the cell operator's page: the agent's own sync read of an idle
arm (``decode_block`` turns each servo's 8-byte block into a sample), and, while
a job runs, only what the job's own ``Present_Position`` reads left in the
connector (``known_positions``): the connector puts no traffic of its own on a
bus a job holds, so load and temperature are unknown then (``None``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from .config import MotorRange
from .identity import MODEL_PROTOCOL, CellMotor
from .safety import to_raw

TELEMETRY_START = 56
"""``Present_Position`` on the STS3215; the block runs through ``Present_Temperature`` (63)."""
TELEMETRY_LENGTH = 8


@dataclass(frozen=True)
class ServoSample:
    """One servo's readings: position in ticks, load in 0.1 % of the rated torque (signed), °C.

    ``load`` and ``temperature`` are None when only the position is known (a job's reads).
    """

    position: int
    load: int | None = None
    temperature: int | None = None


def _sign_magnitude(value: int, sign_bit: int) -> int:
    magnitude = value & ((1 << sign_bit) - 1)
    return -magnitude if value & (1 << sign_bit) else magnitude


def decode_block(block: bytes | list[int]) -> ServoSample:
    """The sample in one servo's 8-byte telemetry block (little-endian, Feetech sign-magnitude)."""
    data = bytes(block)
    if len(data) < TELEMETRY_LENGTH:
        raise ValueError(f"a telemetry block has {TELEMETRY_LENGTH} bytes, got {len(data)}")
    position = _sign_magnitude(int.from_bytes(data[0:2], "little"), 15)
    load = _sign_magnitude(int.from_bytes(data[4:6], "little"), 10)
    return ServoSample(position=position, load=load, temperature=data[7])


def name_samples(
    ids: Mapping[str, int], samples: Mapping[int, ServoSample | None]
) -> dict[str, ServoSample | None]:
    """motor -> sample, for the motors of ``ids`` (motor -> servo id)."""
    return {motor: samples.get(sid) for motor, sid in ids.items()}


def feetech_protocol(motor_model: str | None) -> int | None:
    """The Feetech protocol of ``motor_model``; None when it is no Feetech servo the agent can read."""
    return MODEL_PROTOCOL.get(motor_model) if motor_model is not None else None


def known_positions(
    present: Mapping[bool, tuple[float, Mapping[str, float]]],
    motors: Mapping[str, CellMotor],
    ranges: Mapping[str, MotorRange],
) -> dict[str, ServoSample | None] | None:
    """motor -> its last position the job read (raw ticks), from the connector's record of its reads.

    ``present`` is the handle's ``{normalize: (time, {motor: value})}``: a raw read
    is taken as it is, a normalised one is turned back into ticks with the cell's
    calibration (the one the bus normalises with). None when the job has read no
    position yet. A motor the read did not cover is None.
    """
    raw = present.get(False)
    normalized = present.get(True)
    newest = max((r for r in (raw, normalized) if r is not None), key=lambda r: r[0], default=None)
    if newest is None:
        return None
    samples: dict[str, ServoSample | None] = {}
    for motor in motors or newest[1]:
        value = newest[1].get(motor)
        if value is None:
            samples[motor] = None
        elif newest is raw:
            samples[motor] = ServoSample(position=int(value))
        else:
            cell_motor, motor_range = motors.get(motor), ranges.get(motor)
            samples[motor] = (None if cell_motor is None or motor_range is None
                              else ServoSample(position=to_raw(value, cell_motor.norm_mode, motor_range)))
    return samples
