"""The calibration check: which servo registers differ from the cell's calibration file."""

from __future__ import annotations

import pytest
from armnet_connector.calibration_check import CalibrationMismatch, calibration_mismatches

pytestmark = pytest.mark.unit

CELL = {1: (100, 500, 3500), 2: (-40, 800, 3000)}

CASES = [
    ("identical", {1: (100, 500, 3500), 2: (-40, 800, 3000)}, []),
    ("homing changed", {1: (101, 500, 3500), 2: (-40, 800, 3000)}, [CalibrationMismatch(1, "Homing_Offset", 100, 101)]),
    ("limits changed", {1: (100, 500, 3500), 2: (-40, 0, 4095)},
     [CalibrationMismatch(2, "Min_Position_Limit", 800, 0), CalibrationMismatch(2, "Max_Position_Limit", 3000, 4095)]),
    ("servo silent", {1: (100, 500, 3500), 2: None},
     [CalibrationMismatch(2, r, e, None) for r, e in
      (("Homing_Offset", -40), ("Min_Position_Limit", 800), ("Max_Position_Limit", 3000))]),
    ("servo missing", {1: (100, 500, 3500)},
     [CalibrationMismatch(2, r, e, None) for r, e in
      (("Homing_Offset", -40), ("Min_Position_Limit", 800), ("Max_Position_Limit", 3000))]),
    ("extra servo ignored", {1: (100, 500, 3500), 2: (-40, 800, 3000), 9: (0, 0, 0)}, []),
]


@pytest.mark.parametrize(("case", "read", "expected"), CASES, ids=[c[0] for c in CASES])
def test_mismatches_are_the_registers_that_differ_from_the_cell(case: str, read, expected) -> None:
    assert calibration_mismatches(CELL, read) == expected


def test_a_mismatch_describes_itself_for_the_cell_condition() -> None:
    text = CalibrationMismatch(3, "Homing_Offset", 10, 12).describe()
    assert "servo 3" in text and "Homing_Offset is 12" in text and "10" in text
