"""Checks on a Cell's spec beyond what the CRD can say: a Cell that fails one is never bound.

The CRD rejects most bad Cells at the API server (a safety limit above the
maximum, relative calibration paths, two arms of one cell on one port). This
module repeats those checks for objects stored before the rules existed, and
adds the one the API server cannot make: two Cells of one node on the same
serial port. Of two such cells the older keeps the port (then the name
decides), so the verdict is stable from pass to pass.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace

from .model import Arm, Cell

MAX_SAFETY_LIMIT = 45.0
"""The CRD's maximum for ``safetyLimit`` (LeRobot's ``max_relative_target``, per step)."""


def check_cells(cells: Iterable[Cell]) -> list[Cell]:
    """The cells with ``invalid`` set to the reason each must not be bound (None: fine)."""
    cells = list(cells)
    reasons = {cell.name: check_cell(cell) for cell in cells}
    owners: dict[tuple[str, str], Cell] = {}
    for cell in sorted(cells, key=_age):
        for arm in cell.arms:
            if not arm.port:
                continue
            owner = owners.setdefault((cell.node_name, arm.port), cell)
            if owner is not cell and reasons[cell.name] is None:
                reasons[cell.name] = (
                    f"spec.{arm.name}.port {arm.port} is already used by cell {owner.name} on node "
                    f"{cell.node_name}; give each cell of a node its own serial port"
                )
    return [cell if cell.invalid == reasons[cell.name] else replace(cell, invalid=reasons[cell.name])
            for cell in cells]


def check_cell(cell: Cell) -> str | None:
    """Why this one cell must not be bound, judged on its own spec."""
    if cell.spec_problem:
        return cell.spec_problem
    for arm in cell.arms:
        problem = _check_arm(arm)
        if problem:
            return problem
    for field in ("port", "robot_id"):
        seen: dict[str, str] = {}
        for arm in cell.arms:
            value = getattr(arm, field)
            if value is None:
                continue
            if value in seen:
                label = "port" if field == "port" else "robotId"
                return (f"spec.{arm.name}.{label} {value!r} is also used by spec.{seen[value]}; "
                        f"each arm of a cell needs its own {label}")
            seen[value] = arm.name
    return None


def _check_arm(arm: Arm) -> str | None:
    where = f"spec.{arm.name}"
    if arm.safety_limit is not None and not 0 < arm.safety_limit <= MAX_SAFETY_LIMIT:
        return f"{where}.safetyLimit {arm.safety_limit} is outside (0, {MAX_SAFETY_LIMIT}]"
    for label, path in (("calibrationDir", arm.calibration_dir), ("port", arm.port)):
        if path is None:
            continue
        if not path.startswith("/") or ".." in path.split("/") or "\x00" in path:
            return f"{where}.{label} {path!r} must be an absolute path without '..' segments"
    return None


def _age(cell: Cell) -> tuple[str, str]:
    return (cell.created.isoformat() if cell.created else "~", cell.name)
