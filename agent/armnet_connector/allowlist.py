"""Which classes, methods and attributes a job may reach through ``robot.sock``.

This module owns the allow-list as plain data. Names not listed are refused;
dunder and ``_private`` names are refused before any lookup. Nothing here ever
calls ``getattr`` on a real object.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ClassRules:
    """What a job may do with one allow-listed class."""

    methods: frozenset[str]
    readable: frozenset[str]
    writable: frozenset[str] = frozenset()
    #: Methods that move the arm or rewrite its calibration: refused while the interlock holds.
    motion: frozenset[str] = frozenset()
    #: Methods whose goal-position arguments go through the safety check.
    goal_writers: frozenset[str] = frozenset()


FEETECH = ClassRules(
    # The methods LeRobot's robots call on their bus (docs/reference/feetech-lerobot.md, §4). Absent on
    # purpose: setup_motor / set_baudrate (rewrite servo ids and baud rates of a shared
    # cell), scan_port (opens arbitrary ports).
    methods=frozenset(
        {
            "connect", "disconnect", "read", "write", "sync_read", "sync_write",
            "enable_torque", "disable_torque", "torque_disabled", "configure_motors",
            "read_calibration", "write_calibration", "reset_calibration",
            "set_half_turn_homings", "record_ranges_of_motion", "ping", "broadcast_ping",
            "set_timeout",
        }
    ),
    readable=frozenset(
        {
            "is_connected", "is_calibrated", "motors", "calibration", "port", "protocol_version",
            "default_baudrate", "default_timeout", "normalized_data", "apply_drive_mode",
            "ids", "models",
        }
    ),
    # Nothing is assignable: ``calibration`` is the cell's (read-only), and every other
    # attribute changes how the real bus talks to the hardware.
    writable=frozenset(),
    motion=frozenset(
        {
            "write", "sync_write", "enable_torque", "torque_disabled", "configure_motors",
            "write_calibration", "reset_calibration", "set_half_turn_homings",
        }
    ),
    goal_writers=frozenset({"write", "sync_write"}),
)

CAMERA = ClassRules(
    methods=frozenset({"connect", "disconnect", "read", "async_read", "read_latest"}),
    readable=frozenset(
        {"is_connected", "fps", "width", "height", "color_mode", "warmup_s", "config", "index_or_path"}
    ),
)

ARX5 = ClassRules(
    methods=frozenset({"connect", "disconnect", "get_observation", "send_action", "reset_to_home"}),
    readable=frozenset({"is_connected"}),
    motion=frozenset({"send_action", "reset_to_home"}),
)

#: Methods that rewrite the servos' calibration (EEPROM homing offsets and limits), or
#: (record_ranges_of_motion) record the ranges a calibration job writes next (served without
#: the connector's terminal: policed_bus ends it on the operator's inputs).
#: Refused unless the cell allows calibration jobs.
CALIBRATION_METHODS: dict[str, frozenset[str]] = {
    "FeetechMotorsBus": frozenset(
        {"write_calibration", "reset_calibration", "set_half_turn_homings", "record_ranges_of_motion"}
    ),
}

CLASSES: dict[str, ClassRules] = {
    "FeetechMotorsBus": FEETECH,
    "OpenCVCamera": CAMERA,
    "ARX5Arm": ARX5,
}


def is_private(name: str) -> bool:
    """Dunder and ``_private`` names are never reachable, whatever the class."""
    return name.startswith("_")


def refusal(class_name: str, name: str, *, kind: str) -> str | None:
    """Why ``name`` may not be reached as ``kind`` (get/set/call), or ``None`` when allowed."""
    rules = CLASSES.get(class_name)
    if rules is None:
        return f"class {class_name!r} is not served by this cell; allowed: {sorted(CLASSES)}"
    if is_private(name):
        return f"{class_name}.{name} is private; only public LeRobot attributes are reachable"
    allowed = rules.methods if kind == "call" else rules.writable if kind == "set" else rules.methods | rules.readable
    if name in allowed:
        return None
    verb = {"call": "called", "get": "read", "set": "assigned"}[kind]
    return (
        f"{class_name}.{name} may not be {verb} through the cell connector; "
        f"allowed: {sorted(allowed)}"
    )
