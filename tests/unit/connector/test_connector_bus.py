"""The real LeRobot FeetechMotorsBus behind the connector, on the simulator's pty, via the SDK proxies."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from armnet_runtime.errors import InterlockTripped, SafetyViolation
from armnet_runtime.lerobot.remote_camera import RemoteOpenCVCamera
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

pytestmark = pytest.mark.unit


def wait_until(predicate, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def test_sync_write_moves_the_simulated_arm_and_sync_read_reads_it_back(bus, sim_cell) -> None:
    start = bus.sync_read("Present_Position")
    goal = {motor: value + (5.0 if motor != "gripper" else 10.0) for motor, value in start.items()}
    bus.sync_write("Goal_Position", goal)
    assert wait_until(lambda: not sim_cell.arm.is_moving() and all(
        abs(bus.sync_read("Present_Position")[m] - goal[m]) < 0.5 for m in goal))
    assert bus.read("Present_Position", "elbow_flex") == pytest.approx(goal["elbow_flex"], abs=0.5)


def test_an_oversized_step_is_refused_and_trips_the_interlock(bus, sim_cell, connector) -> None:
    before = sim_cell.arm.goal_positions()
    present = bus.sync_read("Present_Position")
    with pytest.raises(SafetyViolation) as raised:
        bus.sync_write("Goal_Position", {"elbow_flex": present["elbow_flex"] + 45.0})
    assert "elbow_flex" in str(raised.value) and "30.000" in str(raised.value)
    assert sim_cell.arm.goal_positions() == before
    assert connector.interlock.tripped and connector.counters.safety_violations == 1


def test_once_tripped_motion_fails_but_reads_and_torque_disable_work(bus, sim_cell) -> None:
    present = bus.sync_read("Present_Position")
    with pytest.raises(SafetyViolation):
        bus.write("Goal_Position", "shoulder_pan", present["shoulder_pan"] + 90.0)
    with pytest.raises(InterlockTripped):
        bus.sync_write("Goal_Position", {"shoulder_pan": present["shoulder_pan"] + 1.0})
    with pytest.raises(InterlockTripped):
        bus.enable_torque()
    assert bus.sync_read("Present_Position")["shoulder_pan"] == pytest.approx(present["shoulder_pan"], abs=0.5)
    bus.disable_torque()
    assert not any(sim_cell.arm.torque_enabled().values())


def test_a_raw_goal_outside_the_calibrated_range_is_refused(bus, sim_cell) -> None:
    with pytest.raises(SafetyViolation) as raised:
        bus.write("Goal_Position", "wrist_flex", 10, normalize=False)
    assert "calibrated range" in str(raised.value)


def test_re_addressing_a_servo_is_not_allowed(bus, sim_cell) -> None:
    from armnet_runtime.errors import RemoteCallError

    with pytest.raises(RemoteCallError) as raised:
        bus.write("ID", "gripper", 9)
    assert raised.value.error_type == "NotAllowed"
    assert bus.read("ID", "gripper") == 6


def test_torque_disabled_releases_inside_and_re_enables_after(bus, sim_cell) -> None:
    with bus.torque_disabled():
        assert not any(sim_cell.arm.torque_enabled().values())
    assert all(sim_cell.arm.torque_enabled().values())


def test_objects_are_disconnected_when_their_client_goes_away(connector, sim_cell, motors, calibration) -> None:
    remote = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    remote.connect()
    remote.enable_torque()
    assert all(sim_cell.arm.torque_enabled().values())
    object.__getattribute__(remote, "_conn").close()
    assert wait_until(lambda: not connector.cell.live_handles())
    # Disconnecting writes Torque_Enable motor by motor: wait for the last one.
    assert wait_until(lambda: not any(sim_cell.arm.torque_enabled().values()))


def test_return_to_rest_walks_every_motor_to_the_middle_of_its_range(connector, client_for, sim_cell) -> None:
    ranges = connector.cell.ranges["arm"]
    sim_cell.arm.move_by_hand("elbow_flex", ranges["elbow_flex"].range_min + 50)
    sim_cell.arm.move_by_hand("shoulder_pan", ranges["shoulder_pan"].range_max - 50)
    reply = client_for(connector.robot_endpoint).request({"op": "return_to_rest"})
    assert reply == {"ok": True}
    positions = sim_cell.arm.positions()
    for motor, motor_range in ranges.items():
        assert abs(positions[motor] - motor_range.middle) <= 30, motor


def test_return_to_rest_uses_the_jobs_connected_bus(bus, connector, client_for, sim_cell) -> None:
    assert client_for(connector.robot_endpoint).request({"op": "return_to_rest"}) == {"ok": True}
    assert bus.is_connected  # the job's bus was used, not closed
    assert bus.sync_read("Present_Position")


def test_reset_returns_to_rest_then_waits_for_the_operator(connector, client_for, sim_cell) -> None:
    middle = connector.cell.ranges["arm"]["elbow_flex"].middle
    sim_cell.arm.move_by_hand("elbow_flex", middle + 600)
    started = time.monotonic()
    def confirm_once_the_reset_waits() -> None:
        if connector.cell.inputs.wait_reset_pending(30):
            time.sleep(0.3)
            connector.cell.inputs.confirm_reset()

    threading.Thread(target=confirm_once_the_reset_waits, daemon=True).start()
    reply = client_for(connector.operator_endpoint).request({"op": "reset", "request": {"kind": "manual"}})
    assert reply == {"ok": True}
    assert time.monotonic() - started >= 0.3
    assert abs(sim_cell.arm.positions()["elbow_flex"] - middle) <= 30


def test_reset_without_confirmation_times_out_and_trips_the_interlock(connector, client_for) -> None:
    reply = client_for(connector.operator_endpoint).request({"op": "reset"})
    assert reply["ok"] is False and reply["error_type"] == "ResetTimeoutException"
    assert connector.interlock.tripped
    assert client_for(connector.robot_endpoint).request({"op": "return_to_rest"})["error_type"] == "InterlockTripped"


def test_a_client_that_disconnects_mid_call_leaves_the_connector_serving(connector, client_for) -> None:
    import socket

    with socket.socket(socket.AF_UNIX) as sock:
        sock.connect(str(connector.socket_dir / "operator.sock"))
        sock.sendall(b'{"op": "reset"}\n')  # blocks until the reset times out (2 s)
        time.sleep(0.5)
    # The reply to the abandoned reset goes nowhere; the connector keeps serving everyone.
    time.sleep(2.0)
    assert client_for(connector.operator_endpoint).request({"op": "should_stop"}) == {"ok": True, "stop": False}
    assert client_for(connector.robot_endpoint).request({"op": "hello"})["ok"]


def test_a_camera_request_is_served_by_the_simulated_camera(connector, monkeypatch) -> None:
    from lerobot.cameras.opencv import OpenCVCameraConfig

    monkeypatch.setenv("ARMNET_CELL_SOCKET", connector.robot_endpoint)
    camera = RemoteOpenCVCamera(OpenCVCameraConfig(index_or_path="front", fps=30, width=640, height=480))
    camera.connect(warmup=False)
    try:
        frame = camera.async_read(timeout_ms=2000)
        assert isinstance(frame, np.ndarray) and frame.shape == (480, 640, 3) and frame.dtype == np.uint8
        assert camera.is_connected
    finally:
        camera.disconnect()


def test_a_camera_the_cell_does_not_have_is_not_allowed(connector, client_for) -> None:
    from armnet_runtime.wire import encode
    from lerobot.cameras.opencv import OpenCVCameraConfig

    reply = client_for(connector.robot_endpoint).request(
        {"op": "create", "class": "OpenCVCamera", "args": encode([OpenCVCameraConfig(index_or_path="/dev/video9")])}
    )
    assert reply["error_type"] == "NotAllowed" and "front" in reply["error"]


def test_the_arm_selector_maps_each_bus_to_its_arm_on_a_bimanual_cell(make_connector, motors, calibration_path) -> None:
    import json

    from armnet_connector import ConnectorConfig
    from armnet_sim import SimulatedCellProcess
    from lerobot.motors import MotorCalibration

    calibration_file = calibration_path

    with SimulatedCellProcess("bimanual_so101") as cell:
        config = ConnectorConfig.model_validate(
            {
                "arms": {
                    name: {"port": cell.arms[name].port, "calibrationFile": str(calibration_file(f"so101_{name}")),
                           "safetyLimit": 30.0}
                    for name in ("left", "right")
                },
                "simulated": True,
            }
        )
        connector = make_connector(config)
        buses = {}
        for name in ("left", "right"):
            data = json.loads(calibration_file(f"so101_{name}").read_text())
            calibration = {m: MotorCalibration(**entry) for m, entry in data.items()}
            buses[name] = RemoteFeetechMotorsBus(
                port=f"{connector.robot_endpoint}?arm={name}", motors=motors, calibration=calibration
            )
            buses[name].connect()
        buses["left"].enable_torque()
        right_before = cell.arms["right"].goal_positions()
        present = buses["left"].sync_read("Present_Position")
        buses["left"].sync_write("Goal_Position", {"elbow_flex": present["elbow_flex"] + 20.0})
        assert wait_until(lambda: abs(buses["left"].read("Present_Position", "elbow_flex") - present["elbow_flex"] - 20.0) < 0.5)
        assert cell.arms["right"].goal_positions() == right_before
        for bus in buses.values():
            bus.disconnect()


def test_a_yaml_config_file_loads(tmp_path) -> None:
    from armnet_connector import load_config

    path = tmp_path / "cell.yaml"
    path.write_text(
        "arms:\n  arm:\n    port: /dev/ttyACM0\n    safetyLimit: {elbow_flex: 5.0}\n"
        "cameras:\n  front: {index_or_path: 0, fps: 30, width: 640, height: 480}\n"
        "timeoutSeconds: 60\n"
    )
    config = load_config(path)
    assert config.arm_for(None)[1].safety_limit == {"elbow_flex": 5.0}
    assert config.grace_period_seconds == 10 and config.cameras["front"].fps == 30
