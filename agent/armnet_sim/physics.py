"""Joint physics of one position-controlled servo, as a pure step function.

Fidelity target: plausible, not exact. The joint accelerates toward its target
at the servo's Acceleration setting, cruises at a bounded speed, decelerates
and stops on the target; telemetry (load, current, temperature) follows the
tracking error so a moving or blocked joint looks different from an idle one.
Everything works in encoder ticks of the physical frame (before Homing_Offset).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

#: Largest integration step; longer gaps are split so braking stays accurate.
MAX_SUBSTEP_S = 0.005
#: Upper bound on substeps per call, so a long idle gap costs bounded time.
MAX_SUBSTEPS = 100


@dataclass(frozen=True)
class PhysicsParams:
    """Tunable constants of the model (defaults: an STS3215 at 12 V, unloaded)."""

    max_speed: float = 3000.0  # ticks/s, about 264 deg/s
    acceleration_unit: float = 100.0  # ticks/s^2 per unit of the Acceleration register
    ambient_temperature: float = 28.0  # deg C
    heating_per_load: float = 0.02  # deg C above ambient per 0.1 % of load
    thermal_time_constant: float = 60.0  # s
    voltage_decivolts: int = 120


@dataclass(frozen=True)
class JointState:
    position: float  # ticks, physical frame, unwrapped
    velocity: float = 0.0  # ticks/s
    temperature: float = 28.0  # deg C


@dataclass(frozen=True)
class Drive:
    """What the servo's controller is asked to do during a step."""

    torque_on: bool
    target: float  # ticks, physical frame, already clamped to the limits
    speed_limit: float  # ticks/s; 0 means "use the servo's maximum"
    acceleration: int  # register value; 0 means "no ramp"
    #: Torque_Limit, 0.1 % of the stall torque: the effort (load) never exceeds it, a
    #: weaker drive reaches a proportionally lower top speed, and 0 drives nothing.
    effort_limit: int = 1000


@dataclass(frozen=True)
class Telemetry:
    velocity: int  # ticks/s
    load: int  # 0.1 % of max torque, signed
    current: int  # units of 6.5 mA
    temperature: int  # deg C
    voltage: int  # 0.1 V
    moving: bool


def step(state: JointState, drive: Drive, dt: float, params: PhysicsParams) -> JointState:
    """Advance the joint by ``dt`` seconds."""
    if dt <= 0:
        return state
    temperature = _relax_temperature(state, drive, dt, params)
    if not drive.torque_on:
        return replace(state, velocity=0.0, temperature=temperature)
    if drive.effort_limit <= 0:
        return replace(state, velocity=0.0, temperature=temperature)
    if state.velocity == 0.0 and state.position == drive.target:
        return replace(state, temperature=temperature)
    substeps = min(MAX_SUBSTEPS, max(1, math.ceil(dt / MAX_SUBSTEP_S)))
    h = dt / substeps
    position, velocity = state.position, state.velocity
    for _ in range(substeps):
        position, velocity = _substep(position, velocity, drive, h, params)
        if velocity == 0.0 and position == drive.target:
            break
    return JointState(position=position, velocity=velocity, temperature=temperature)


def _substep(
    position: float, velocity: float, drive: Drive, h: float, params: PhysicsParams
) -> tuple[float, float]:
    error = drive.target - position
    cruise = params.max_speed * min(1.0, drive.effort_limit / 1000.0)
    if 0 < drive.speed_limit < cruise:
        cruise = float(drive.speed_limit)
    accel = drive.acceleration * params.acceleration_unit
    if accel > 0:
        # Fastest speed from which the joint can still brake before the target.
        cruise = min(cruise, math.sqrt(2.0 * accel * abs(error)))
    desired = math.copysign(cruise, error)
    if accel > 0:
        dv = max(-accel * h, min(accel * h, desired - velocity))
        velocity += dv
    else:
        velocity = desired
    new_position = position + velocity * h
    if (drive.target - new_position) * error <= 0:
        return drive.target, 0.0
    return new_position, velocity


def _relax_temperature(state: JointState, drive: Drive, dt: float, params: PhysicsParams) -> float:
    load = abs(_load(state, drive)) if drive.torque_on else 0
    equilibrium = params.ambient_temperature + params.heating_per_load * load
    alpha = 1.0 - math.exp(-dt / params.thermal_time_constant)
    return state.temperature + (equilibrium - state.temperature) * alpha


def _load(state: JointState, drive: Drive) -> int:
    """Holding effort plus a term growing with tracking error and speed, capped at Torque_Limit."""
    if not drive.torque_on:
        return 0
    error = drive.target - state.position
    effort = 40.0 + 2.0 * abs(error) + 0.05 * abs(state.velocity)
    magnitude = int(min(1000.0, float(max(0, drive.effort_limit)), effort))
    return magnitude if error >= 0 else -magnitude


def telemetry(state: JointState, drive: Drive, params: PhysicsParams) -> Telemetry:
    """Register-level readings for the current state."""
    load = _load(state, drive)
    moving = state.velocity != 0.0 or (drive.torque_on and state.position != drive.target)
    return Telemetry(
        velocity=int(round(state.velocity)),
        load=load,
        current=int(abs(load) * 0.4) + (8 if moving else 0),
        temperature=int(round(state.temperature)),
        voltage=params.voltage_decivolts,
        moving=moving,
    )
