"""``armnet run`` end to end, with nothing mocked.

job script -> ``armnet-runtime`` -> the LeRobot import swap -> remote proxy ->
robot.sock -> the real connector -> the real ``FeetechMotorsBus`` -> pty -> the
cell simulator. The main example runs through the real ``armnet`` command in a
subprocess; the others run the same code path in-process (``run_local_job``)
so the test can read the simulator's joints before the cell is torn down.

Jobs that use LeRobot import it (and torch) at start-up, which takes seconds on a
busy machine: their timeouts leave room for that. Jobs that do not start in a
fraction of a second (the SDK imports no LeRobot before ``@main``).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest
from armnet_core import JobResult, JobStatus
from armnet_launch.sim_cell import LocalCell
from armnet_local.cli import add_arguments, parse_request, run_local_job
from armnet_local.render import TerminalRenderer

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(600)]

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "runtime" / "examples"
ARMNET = Path(sys.executable).parent / "armnet"
BODY_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")
ARRIVED = 0.75  # degrees


def armnet_run(*argv: str, env: dict[str, str] | None = None) -> tuple[subprocess.CompletedProcess[str], JobResult]:
    """The real command, as a user runs it; the last stdout line is the JobResult JSON."""
    assert ARMNET.exists(), f"{ARMNET} missing: run scripts/setup.d/10-python.sh to install armnet into the venv"
    proc = subprocess.run(
        [str(ARMNET), "run", *argv, "--json"],
        capture_output=True,
        text=True,
        timeout=420,
        stdin=subprocess.DEVNULL,
        start_new_session=True,  # no controlling terminal: nobody can confirm a reset by hand
        env=env,
    )
    lines = proc.stdout.strip().splitlines()
    assert lines, f"armnet run printed nothing on stdout; stderr:\n{proc.stderr}"
    return proc, JobResult.model_validate_json(lines[-1])


class InProcessRun:
    """``armnet run`` without the process boundary, keeping what the simulator saw."""

    def __init__(self, *argv: str) -> None:
        parser = argparse.ArgumentParser()
        add_arguments(parser)
        self.request = parse_request(parser.parse_args(list(argv)))
        self.out, self.err = io.StringIO(), io.StringIO()
        self.joints: dict[str, dict[str, float]] = {}
        self.raw_positions: dict[str, dict[str, int]] = {}
        self.trip: str | None = None

    def _inspect(self, cell: LocalCell, result: JobResult) -> None:
        assert cell.sim is not None and cell.connector is not None
        trip = cell.connector.interlock.trip_info
        self.trip = trip.message if trip is not None else None
        for name, arm in cell.sim.arms.items():
            self.joints[name] = arm.normalized_positions()
            self.raw_positions[name] = arm.positions()

    def __call__(self) -> JobResult:
        renderer = TerminalRenderer(out=self.out, err=self.err)
        return run_local_job(self.request, renderer, inspect=self._inspect)


def write_job(tmp_path: Path, name: str, body: str) -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(body))
    return path


def assert_succeeded(result: JobResult) -> Any:
    assert result.status is JobStatus.SUCCEEDED, f"{result}\nstdout:\n{result.stdout}\nstderr:\n{result.stderr}"
    return result.return_value


BUS_PREAMBLE = """
    import json, time
    from pathlib import Path
    from armnet_runtime import Context, main
    from lerobot.motors import Motor, MotorCalibration, MotorNormMode
    from lerobot.motors.feetech import FeetechMotorsBus

    JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")

    def open_bus(port, calibration_file):
        raw = json.loads(Path(calibration_file).read_text())
        motors = {n: Motor(i, "sts3215", MotorNormMode.DEGREES) for i, n in enumerate(JOINTS, 1)}
        motors["gripper"] = Motor(6, "sts3215", MotorNormMode.RANGE_0_100)
        bus = FeetechMotorsBus(port=port, motors=motors,
                               calibration={n: MotorCalibration(**raw[n]) for n in motors})
        bus.connect()
        bus.enable_torque()
        return bus
"""


def test_the_bus_loop_example_runs_through_the_armnet_command() -> None:
    proc, result = armnet_run(str(EXAMPLES / "bus_loop.py"), "--embodiment", "lerobot/so-101", "--timeout", "300")
    value = assert_succeeded(result)
    assert proc.returncode == 0
    assert "[progress] arm: done" in proc.stdout
    assert proc.stdout.rstrip().splitlines()[-2].startswith("  return_value:")  # __str__ just before the JSON
    for joint in BODY_JOINTS:
        assert abs(value["final_positions"][joint]) <= ARRIVED  # out and back to the start pose


def test_the_simulator_ends_where_the_job_commanded(tmp_path: Path) -> None:
    job = write_job(tmp_path, "command.py", BUS_PREAMBLE + """
    @main
    def run(ctx: Context):
        bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
        start = bus.sync_read("Present_Position")
        goals = {j: start[j] + (3.0 if start[j] <= 0 else -3.0) + 1.5 * k for k, j in enumerate(JOINTS[:3])}
        for fraction in (0.5, 1.0):  # two writes each, well under the safety limit
            bus.sync_write("Goal_Position", {j: start[j] + fraction * (g - start[j]) for j, g in goals.items()})
            time.sleep(0.3)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            now = bus.sync_read("Present_Position")
            if all(abs(now[j] - g) < 0.5 for j, g in goals.items()):
                break
            time.sleep(0.05)
        bus.disconnect(disable_torque=False)
        return {"goals": goals, "read_back": {j: now[j] for j in goals}}
    """)
    run = InProcessRun(str(job), "--timeout", "300")
    value = assert_succeeded(run())
    for joint, goal in value["goals"].items():
        assert abs(run.joints["arm"][joint] - goal) <= ARRIVED, (joint, run.joints["arm"][joint], goal)
        assert abs(value["read_back"][joint] - goal) <= ARRIVED


def test_the_camera_example_reads_a_640x480_rgb_frame() -> None:
    value = assert_succeeded(InProcessRun(str(EXAMPLES / "camera.py"), "--timeout", "300")())
    assert value["shape"] == [480, 640, 3]
    assert value["async_shape"] == [480, 640, 3]
    assert value["dtype"] == "uint8"


def test_the_bimanual_example_moves_both_arms_and_the_simulator_agrees() -> None:
    run = InProcessRun(str(EXAMPLES / "bimanual.py"), "--preset", "bimanual_so101", "--timeout", "400")
    value = assert_succeeded(run())
    assert set(value["final_positions"]) == {"left", "right"}
    for arm in ("left", "right"):
        for joint, position in value["final_positions"][arm].items():
            assert abs(run.joints[arm][joint] - position) <= ARRIVED, (arm, joint)
    assert "[progress] right: done" in run.out.getvalue()


def test_an_oversized_step_trips_the_safety_limit_and_the_interlock_then_holds_under_trip(tmp_path: Path) -> None:
    job = write_job(tmp_path, "oversized.py", BUS_PREAMBLE + """
    from armnet_runtime.errors import InterlockTripped, SafetyViolation

    @main
    def run(ctx: Context):
        bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
        start = bus.sync_read("Present_Position")["shoulder_pan"]
        seen = {}
        try:
            bus.sync_write("Goal_Position", {"shoulder_pan": start + 5 * ctx.cell.safety_limit})
            seen["oversized"] = "accepted"
        except SafetyViolation as exc:
            seen["oversized"] = type(exc).__name__
            seen["message"] = str(exc)
        try:
            bus.sync_write("Goal_Position", {"shoulder_pan": start + 0.5})
            seen["small_after"] = "accepted"
        except InterlockTripped as exc:
            seen["small_after"] = type(exc).__name__
        time.sleep(0.5)
        seen["read_after"] = bus.sync_read("Present_Position")["shoulder_pan"]
        seen["start"] = start
        bus.disconnect(disable_torque=False)
        return seen
    """)
    cell_file = tmp_path / "cell.yaml"
    cell_file.write_text("safety_policy: trip\n")
    run = InProcessRun(str(job), "--timeout", "300", "--cell-config", str(cell_file))
    value = assert_succeeded(run())
    assert value["oversized"] == "SafetyViolation"
    assert "shoulder_pan" in value["message"]
    assert value["small_after"] == "InterlockTripped"
    assert abs(value["read_after"] - value["start"]) <= ARRIVED  # reads still work; nothing moved
    assert abs(run.joints["arm"]["shoulder_pan"] - value["start"]) <= ARRIVED


def test_an_oversized_step_is_clamped_by_default_and_the_job_keeps_moving(tmp_path: Path) -> None:
    job = write_job(tmp_path, "clamped.py", BUS_PREAMBLE + """
    @main
    def run(ctx: Context):
        bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
        start = bus.sync_read("Present_Position")["shoulder_pan"]
        bus.sync_write("Goal_Position", {"shoulder_pan": start + 5 * ctx.cell.safety_limit})  # clamped
        time.sleep(1.0)
        after = bus.sync_read("Present_Position")["shoulder_pan"]
        bus.sync_write("Goal_Position", {"shoulder_pan": after - 1.0})  # motion still allowed
        bus.disconnect(disable_torque=False)
        return {"start": start, "after": after, "limit": ctx.cell.safety_limit}
    """)
    run = InProcessRun(str(job), "--timeout", "300")
    value = assert_succeeded(run())
    moved = value["after"] - value["start"]
    assert 0 < moved <= value["limit"] + ARRIVED  # one limit's worth, not five


def test_hostile_register_writes_and_calibration_are_refused_under_armnet_run(tmp_path: Path) -> None:
    job = write_job(tmp_path, "hostile.py", BUS_PREAMBLE + """
    from armnet_runtime.errors import RemoteCallError

    WRITES = [("Operating_Mode", 1), ("Min_Position_Limit", 0), ("Max_Position_Limit", 4095),
              ("Homing_Offset", 500), ("Torque_Limit", 0), ("Goal_Velocity", 3000), ("Lock", 0)]

    @main
    def run(ctx: Context):
        bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
        refused = {}
        for register, value in WRITES:
            try:
                bus.write(register, "wrist_flex", value, normalize=False)
                refused[register] = "accepted"
            except RemoteCallError as exc:
                refused[register] = exc.error_type
        for method in ("set_half_turn_homings", "record_ranges_of_motion"):
            try:
                getattr(bus, method)()
                refused[method] = "accepted"
            except RemoteCallError as exc:
                refused[method] = exc.error_type
        calibrated = bus.is_calibrated
        bus.disconnect()
        return {"refused": refused, "calibrated": calibrated}
    """)
    value = assert_succeeded(InProcessRun(str(job), "--timeout", "300")())
    assert set(value["refused"].values()) == {"NotAllowed"}, value["refused"]
    assert value["calibrated"] is True


def test_a_job_ignoring_the_timeout_is_killed_within_1s_of_the_grace_window_end(tmp_path: Path) -> None:
    job = write_job(tmp_path, "stubborn.py", """
    import time
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        print("looping and ignoring the deadline", flush=True)
        while True:
            time.sleep(0.05)
    """)
    # 8 s: the job imports no LeRobot, so it reaches its loop within a second or two even on
    # a loaded host (bench/startup.py); the deadline itself is what is measured.
    timeout, grace = 8, 2.0
    result = InProcessRun(str(job), "--timeout", str(timeout), "--grace", str(grace))()
    assert result.status is JobStatus.TIMEOUT, str(result)
    assert "looping and ignoring the deadline" in result.stdout  # it really was running its loop
    assert result.exit_code == -9
    assert result.started_at is not None and result.finished_at is not None
    overrun = (result.finished_at - result.started_at).total_seconds() - (timeout + grace)
    assert 0 <= overrun < 1.0, f"killed {overrun:.3f} s after the grace window closed"


def test_the_time_before_main_counts_against_the_timeout(tmp_path: Path) -> None:
    """The deadline runs from the cell's start, so a script whose imports outlast it never
    reaches ``@main``: it ends ``timeout``, killed at the grace window's end (docs/local-run.md)."""
    job = write_job(tmp_path, "slow_imports.py", """
    import time
    print("importing", flush=True)
    time.sleep(60)  # stands for imports that outlast the job's timeout
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        print("reached main", flush=True)
    """)
    result = InProcessRun(str(job), "--timeout", "1", "--grace", "1")()
    assert result.status is JobStatus.TIMEOUT, str(result)
    assert "importing" in result.stdout and "reached main" not in result.stdout
    assert result.exit_code == -9


def test_the_interlock_trip_at_the_timeout_names_the_timeout_the_user_gave(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    job = write_job(tmp_path, "waits.py", """
    import time
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        while not ctx.cell.is_shutting_down():
            time.sleep(0.05)
    """)
    run = InProcessRun(str(job), "--timeout", "2", "--grace", "30")
    with caplog.at_level("WARNING", logger="armnet_connector"):
        result = run()
    assert result.status is JobStatus.TIMEOUT, str(result)
    assert run.trip == "the job exceeded its timeout of 2 s"
    assert "the job exceeded its timeout of 2 s: interlock tripped, grace window of 30 s open" in caplog.messages
    assert result.error is not None and result.error.startswith("job exceeded its timeout of 2 s;")


def test_a_job_polling_is_shutting_down_ends_timeout_with_its_return_value() -> None:
    result = InProcessRun(str(EXAMPLES / "graceful_shutdown.py"), "--timeout", "30", "--grace", "20")()
    assert result.status is JobStatus.TIMEOUT, str(result)
    assert result.exit_code == 0
    assert result.return_value["stopped_for_shutdown"] is True
    assert result.return_value["steps"] > 0
    assert result.error is not None and "stopped within" in result.error


def test_a_reset_nobody_confirms_raises_reset_timeout_in_the_job(tmp_path: Path) -> None:
    cell = tmp_path / "cell.json"
    cell.write_text('{"reset_timeout_seconds": 1}')
    proc, result = armnet_run(str(EXAMPLES / "reset.py"), "--cell-config", str(cell), "--timeout", "300")
    assert result.status is JobStatus.FAILED, str(result)
    assert proc.returncode == 1
    assert result.traceback is not None and "ResetTimeoutException" in result.traceback


def test_an_auto_confirmed_reset_returns() -> None:
    value = assert_succeeded(InProcessRun(str(EXAMPLES / "reset.py"), "--auto-confirm-reset", "--timeout", "300")())
    assert value["resets"] == 1


def test_image_without_a_container_engine_says_so_and_fails(tmp_path: Path) -> None:
    env = dict(os.environ, DOCKER_HOST=f"unix://{tmp_path / 'no-engine.sock'}")
    proc, result = armnet_run(str(EXAMPLES / "hello.py"), "--image", "armnet/hello:dev", env=env)
    assert proc.returncode == 1
    assert result.status is JobStatus.FAILED
    assert "no container engine answers" in proc.stderr
    assert result.error is not None and "DOCKER_HOST" in result.error


def completion_cell_file(tmp_path: Path) -> Path:
    """A local cell whose monitor looks for the simulator's end-effector disc on its target pad."""
    from armnet_sim.render import target_region

    left, top, width, height = target_region(640, 480)
    cell = tmp_path / "cell.json"
    cell.write_text(json.dumps({"completion": {
        "camera": "front", "region": {"left": left, "top": top, "width": width, "height": height},
        "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 80},
        "consecutiveFrames": 3, "rateHz": 15,
    }}))
    return cell


REACH_JOB = BUS_PREAMBLE + """
    TARGET = {"shoulder_lift": 20.0, "elbow_flex": 40.0, "wrist_flex": 0.0}  # the simulator's TARGET_POSE

    @main
    def run(ctx: Context):
        goal = dict(TARGET) if ctx.args["reach"] else {**TARGET, "elbow_flex": 25.0}
        before = tuple(ctx.cell.is_complete(block=True))
        bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            present = bus.sync_read("Present_Position")
            if all(abs(present[j] - g) < 0.5 for j, g in goal.items()):
                break
            bus.sync_write("Goal_Position", {j: present[j] + max(-8.0, min(8.0, g - present[j])) for j, g in goal.items()})
            time.sleep(0.05)
        checks = []
        for _ in range(10):  # each waits for a frame captured after it to be scored
            status = ctx.cell.is_complete(block=True)
            checks.append(tuple(status))
            if status.complete:
                break
        bus.disconnect(disable_torque=False)
        return {"before": before, "last": checks[-1], "checks": len(checks), "at": present}
"""


@pytest.mark.parametrize("reach", [True, False], ids=["onto the target", "short of the target"])
def test_the_cells_monitor_scores_a_job_complete_only_when_it_drove_the_arm_onto_the_target(
    tmp_path: Path, reach: bool,
) -> None:
    job = write_job(tmp_path, "reach.py", REACH_JOB)
    proc, result = armnet_run(str(job), "--cell-config", str(completion_cell_file(tmp_path)),
                              "--args", json.dumps({"reach": reach}), "--timeout", "300")
    value = assert_succeeded(result)
    assert value["before"] == [False, False]  # the arm starts away from the target
    assert value["last"] == ([True, True] if reach else [False, False]), value


def test_what_a_job_writes_to_its_output_directory_is_kept_with_output(tmp_path: Path) -> None:
    job = write_job(tmp_path, "writer.py", """
    import os
    from pathlib import Path
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        out = Path(os.environ["ARMNET_OUTPUT_DIR"])
        (out / "episode_0.txt").write_text("recorded")
        return os.environ["HF_LEROBOT_HOME"]
    """)
    kept = tmp_path / "kept"
    lerobot_home = assert_succeeded(InProcessRun(str(job), "--output", str(kept))())
    assert (kept / "episode_0.txt").read_text() == "recorded"
    assert lerobot_home == str(kept / "lerobot")  # LeRobot's datasets land in the kept directory
