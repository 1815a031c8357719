"""Hostile jobs against the cell, checked on the servos' side.

Random and hostile create arguments (aliased names, other units, protocols,
calibrations), random (register, motor, value) writes, goal steps, method calls,
attribute writes, closed handles and fresh connections, under both safety
policies. After every operation the simulator is asked what the servos did
(and scservo_sdk's process-global byte order is checked, the connector runs in
this process):
no goal ever stepped beyond the cell's limit from where the servo was; and after
every connector stop, torque is off on every servo, every other register is as the
job found it (EEPROM never changed, tuned RAM registers restored) and ``Lock`` is set.

Short by default (a few seconds in the suite); ``ARMNET_FUZZ_EXAMPLES=500`` (or
``bench/connector_policy_fuzz.sh``) runs it longer.
"""

from __future__ import annotations

import math
import os
from typing import Any

import pytest
from armnet_connector import Connector, LocalOperatorInputs
from armnet_connector.allowlist import FEETECH
from armnet_connector.config import read_calibration_file
from armnet_connector.identity import cell_motor_table
from armnet_connector.registers import STS3215
from armnet_connector.safety import ticks_per_unit
from armnet_runtime.transport import PersistentConnection
from armnet_runtime.wire import encode
from armnet_sim.control_table import REGISTERS as SIM_REGISTERS
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.unit

EXAMPLES = int(os.environ.get("ARMNET_FUZZ_EXAMPLES", "12"))
LIMIT = 30.0
MOTORS = ["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"]
NORMS = ["degrees", "range_0_100", "range_m100_100"]


def lerobot_registers() -> list[str]:
    from lerobot.motors.feetech.tables import MODEL_CONTROL_TABLE

    return sorted(MODEL_CONTROL_TABLE["sts3215"])


REGISTERS = lerobot_registers()
#: Registers compared after each example: every byte a write can reach, as the simulator names them.
WRITABLE = [r.name for r in SIM_REGISTERS if not r.read_only]

motor_names = st.sampled_from(MOTORS + ["elbow", "", "__class__"]) | st.integers(0, 300)
numbers = (
    st.integers(-70000, 70000) | st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from([0, 1, 2, 3, 254, 1000, 4095, 32767])
)
hostile = numbers | st.text(max_size=6) | st.none() | st.lists(st.integers(), max_size=2)


@st.composite
def job_motors(draw: Any) -> dict[str, Any]:
    """A job's ``motors``: mostly the cell's own table, sometimes aliased, re-united or re-numbered."""
    from lerobot.motors import Motor, MotorNormMode

    names = draw(st.lists(st.sampled_from(MOTORS), min_size=1, max_size=6, unique=True))
    motors = {}
    for name in names:
        servo_id = MOTORS.index(name) + 1
        norm = "range_0_100" if name == "gripper" else "degrees"
        if draw(st.integers(0, 5)) == 0:
            servo_id = draw(st.integers(1, 8))
        if draw(st.integers(0, 5)) == 0:
            norm = draw(st.sampled_from(NORMS))
        motors[name] = Motor(servo_id, draw(st.sampled_from(["sts3215"] * 5 + ["scs0009", "sts3250"])), MotorNormMode(norm))
    return motors


def create_request(draw: Any) -> dict[str, Any]:
    kwargs: dict[str, Any] = {"motors": draw(job_motors())}
    choice = draw(st.integers(0, 9))
    if choice == 0:
        kwargs["protocol_version"] = draw(st.sampled_from([1, 2, -1, True, "0"]))
    elif choice == 1:
        from lerobot.motors import MotorCalibration

        kwargs["calibration"] = {m: MotorCalibration(mo.id, 0, draw(st.integers(-2047, 2047)), 0, 4095)
                                 for m, mo in kwargs["motors"].items()}
    elif choice == 2:
        kwargs["motors"] = draw(hostile)
    return kwargs


@st.composite
def operations(draw: Any) -> list[tuple[str, Any]]:
    ops: list[tuple[str, Any]] = [("create", {"motors": "CELL"})]
    for _ in range(draw(st.integers(1, 14))):
        kind = draw(st.sampled_from(
            ["create", "write", "write", "sync_write", "step", "step", "sync_step", "call", "setattr", "close",
             "reconnect", "torque"]
        ))
        if kind == "create":
            ops.append((kind, create_request(draw)))
        elif kind == "write":
            ops.append((kind, (draw(st.sampled_from(REGISTERS + ["Bogus"])), draw(motor_names), draw(hostile),
                               draw(st.booleans()))))
        elif kind == "sync_write":
            values = draw(hostile | st.dictionaries(motor_names, hostile, max_size=3))
            ops.append((kind, (draw(st.sampled_from(REGISTERS)), values, draw(st.booleans()))))
        elif kind == "step":
            ops.append((kind, (draw(st.sampled_from(MOTORS)), draw(st.integers(-900, 900)))))
        elif kind == "sync_step":
            ops.append((kind, draw(st.dictionaries(st.sampled_from(MOTORS), st.integers(-900, 900), min_size=1))))
        elif kind == "call":
            method = draw(st.sampled_from(sorted(FEETECH.methods)))
            ops.append((kind, (method, draw(st.lists(hostile, max_size=2)))))
        elif kind == "setattr":
            ops.append((kind, (draw(st.sampled_from(sorted(FEETECH.readable) + ["port_handler", "_write"])),
                               draw(hostile))))
        elif kind == "torque":
            ops.append((kind, draw(st.booleans())))
        else:
            ops.append((kind, None))
    return ops


class Client:
    """A raw protocol client: a hostile job does not need the SDK's proxies."""

    def __init__(self, endpoint: str) -> None:
        self.conn = PersistentConnection(endpoint, timeout=30)

    def request(self, payload: dict[str, Any]) -> dict[str, Any]:
        reply = self.conn.request(payload)
        assert isinstance(reply.get("ok"), bool), reply
        return reply

    def call(self, object_id: str, method: str, *args: Any, **kwargs: Any) -> dict[str, Any]:
        return self.request({"op": "call", "object_id": object_id, "method": method,
                             "args": encode(list(args)), "kwargs": encode(kwargs)})

    def close(self) -> None:
        self.conn.close()


class Cell:
    """The simulator's view: limits in ticks, and a snapshot of every writable register."""

    def __init__(self, sim_cell: Any, calibration: Any) -> None:
        self.arm = sim_cell.arm
        ranges = read_calibration_file(calibration)
        table = cell_motor_table({m: r.id for m, r in ranges.items()}, "sts3215")
        self.limit_ticks = {m: LIMIT * ticks_per_unit(table[m].norm_mode, ranges[m]) for m in ranges}

    def registers(self) -> dict[tuple[str, str], int]:
        return {(m, r): self.arm.register(m, r) for m in MOTORS for r in WRITABLE}

    def check_step(self, before: dict[str, int], goals_before: dict[str, int]) -> None:
        after = self.arm.positions()
        for motor, goal in self.arm.goal_positions().items():
            if goal == goals_before[motor]:
                continue
            moved = abs(after[motor] - before[motor])
            nearest = min(abs(goal - before[motor]), abs(goal - after[motor]))
            assert nearest <= self.limit_ticks[motor] + moved + 2, (motor, before[motor], goal, after[motor])

    def check_registers(self, initial: dict[tuple[str, str], int]) -> None:
        """After the stop every register is as the job found it, but the goal and torque (the stop's own)."""
        for (motor, register), value in self.registers().items():
            old = initial[(motor, register)]
            if register in ("Goal_Position", "Torque_Enable"):
                continue
            assert value == old, (motor, register, old, value, STS3215.get(register))
        assert all(self.arm.register(m, "Lock") == 1 for m in MOTORS)


def run(client: Client, op: str, arg: Any, state: dict[str, Any], endpoint: str, cell: Cell, cell_motors: Any) -> None:
    objects = state["objects"]
    target = objects[-1] if objects else "o404"
    if op == "create":
        kwargs = dict(arg)
        if kwargs.get("motors") == "CELL":
            kwargs["motors"] = cell_motors
        reply = client.request({"op": "create", "class": "FeetechMotorsBus",
                                "kwargs": encode({"port": endpoint, **kwargs})})
        if reply["ok"]:
            objects.append(reply["object_id"])
            client.call(reply["object_id"], "connect")
    elif op == "write":
        register, motor, value, normalize = arg
        client.call(target, "write", register, motor, value, normalize=normalize)
    elif op == "sync_write":
        register, values, normalize = arg
        client.call(target, "sync_write", register, values, normalize=normalize)
    elif op == "step":
        motor, delta = arg
        client.call(target, "write", "Goal_Position", motor, cell.arm.positions()[motor] + delta, normalize=False)
    elif op == "sync_step":
        positions = cell.arm.positions()
        client.call(target, "sync_write", "Goal_Position", {m: positions[m] + d for m, d in arg.items()},
                    normalize=False)
    elif op == "call":
        method, args = arg
        if method not in ("record_ranges_of_motion",):  # refused anyway; never blocks on stdin
            client.call(target, method, *args)
        else:
            client.call(target, method)
    elif op == "setattr":
        name, value = arg
        client.request({"op": "setattr", "object_id": target, "name": name, "value": encode(value)})
    elif op == "torque":
        client.call(target, "enable_torque" if arg else "disable_torque")
    elif op == "close":
        if objects:
            client.request({"op": "close", "object_id": objects.pop()})
    elif op == "reconnect":
        client.close()
        state["client"] = Client(endpoint)
        objects.clear()


@settings(max_examples=EXAMPLES, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(ops=operations(), policy=st.sampled_from(["clamp", "trip"]))
def test_no_hostile_job_steps_a_servo_past_the_limit_or_changes_what_the_policy_protects(
    ops: list[tuple[str, Any]], policy: str, sim_cell, socket_dir, cell_config, motors, calibration_path
) -> None:
    import scservo_sdk.scservo_def as scs_def

    cell = Cell(sim_cell, calibration_path("so101"))
    initial = cell.registers()
    config = cell_config(sim_cell, safetyPolicy=policy, presentPositionMaxAgeMs=0)
    connector = Connector(config, socket_dir, inputs=LocalOperatorInputs()).start()
    try:
        state: dict[str, Any] = {"objects": [], "client": Client(connector.robot_endpoint)}
        for op, arg in ops:
            before, goals = cell.arm.positions(), cell.arm.goal_positions()
            run(state["client"], op, arg, state, connector.robot_endpoint, cell, motors)
            cell.check_step(before, goals)
            assert scs_def.SCS_END == 0, f"{op} {arg!r} flipped scservo_sdk's process-global byte order"
        state["client"].close()
    finally:
        connector.stop()
    assert not any(cell.arm.torque_enabled().values())
    cell.check_registers(initial)
    assert all(math.isfinite(v) for v in cell.arm.positions().values())
