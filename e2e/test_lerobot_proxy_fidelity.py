"""Under ``armnet run``, LeRobot's bus and camera proxies behave like the objects they stand for.

The job (e2e/jobs/proxy_fidelity.py) uses only LeRobot's public API. Where a
bare arm gives a definite answer, the test computes it from LeRobot's own
``FeetechMotorsBus`` on the simulator and compares.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from armnet_core import JobStatus
from armnet_sim import build_cell

from e2e.test_local_run import InProcessRun

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(600)]

JOB = Path(__file__).parent / "jobs" / "proxy_fidelity.py"


@pytest.fixture(scope="module")
def seen() -> dict[str, Any]:
    result = InProcessRun(str(JOB), "--timeout", "300")()
    assert result.status is JobStatus.SUCCEEDED, f"{result}\n{result.stderr}"
    value: dict[str, Any] = result.return_value
    return value


@pytest.fixture(scope="module")
def bare() -> dict[str, Any]:
    """The same questions asked of LeRobot's real FeetechMotorsBus on a simulated arm."""
    from lerobot.motors.feetech import FeetechMotorsBus
    from lerobot.motors.motors_bus import MotorsBusBase, SerialMotorsBus

    with build_cell("so101") as cell:
        arm = next(iter(cell.arms.values()))
        bus = FeetechMotorsBus(port=arm.port, motors={})
        return {
            "isinstance_bus": [isinstance(bus, SerialMotorsBus), isinstance(bus, MotorsBusBase)],
            "hasattr_setup_motor": hasattr(bus, "setup_motor"),
            "getattr_default": getattr(bus, "no_such_thing", "default"),
            "ctrl_table_goal": list(bus.model_ctrl_table["sts3215"]["Goal_Position"]),
            "baudrate": bus.port_handler.baudrate,
        }


@pytest.mark.parametrize("key", ["isinstance_bus", "hasattr_setup_motor", "getattr_default", "ctrl_table_goal", "baudrate"])
def test_the_proxy_answers_as_lerobots_own_bus_does(seen: dict[str, Any], bare: dict[str, Any], key: str) -> None:
    assert seen[key] == bare[key]


def test_a_name_outside_the_allow_list_is_a_missing_attribute(seen: dict[str, Any]) -> None:
    assert seen["hasattr_sync_reader"] is False  # a live GroupSyncRead never leaves the connector


def test_calling_a_refused_method_is_a_clear_refusal_naming_it(seen: dict[str, Any]) -> None:
    kind, message = seen["setup_motor"]
    assert kind == "RemoteCallError"
    assert "setup_motor may not be called" in message


def test_port_handler_reads_give_the_customers_endpoint_not_the_device(seen: dict[str, Any]) -> None:
    assert seen["port_name"].startswith("unix://")


def test_scan_port_reports_the_cells_arm(seen: dict[str, Any]) -> None:
    assert seen["scan_port"] == {"1000000": [1, 2, 3, 4, 5, 6]}


def test_a_foreign_port_or_camera_is_a_connection_error(seen: dict[str, Any]) -> None:
    assert seen["foreign_port"] == "ConnectionError"
    assert seen["foreign_camera"] == "ConnectionError"


def test_key_error_text_has_one_layer_of_quotes(seen: dict[str, Any]) -> None:
    assert seen["keyerror"].count("'") <= 2 and '"' not in seen["keyerror"]


def test_the_camera_is_a_camera_and_a_context_manager(seen: dict[str, Any]) -> None:
    assert seen["isinstance_cam"] is True
    assert seen["camera_connected_in_with"] is True
    assert seen["camera_connected_after_with"] is False
    assert seen["find_cameras"] == ["front"]
    assert seen["read_color_mode"] == [480, 640, 3]
    rotation, width, height, backend = seen["camera_facts"]
    assert (rotation, width, height) == (None, 640, 480)
    assert backend.startswith("Cv2Backends.")
