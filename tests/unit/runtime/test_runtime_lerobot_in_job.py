"""LeRobot's own commands started inside a job: swapped onto the connector, cell-owned ones refused at once.

Each case is a fresh interpreter that reads the ``.pth`` the runtime image installs
(``site.addsitedir`` on a directory holding it), with the env a job gets, and runs
LeRobot's real command entry point.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from armnet_runtime import env as env_keys
from armnet_runtime.lerobot.in_job import CALIBRATE_REFUSAL, SETUP_MOTORS_REFUSAL, write_pth

pytestmark = pytest.mark.unit


def interpreter(tmp_path: Path, code: str, **job_env: str) -> subprocess.CompletedProcess[str]:
    site_dir = tmp_path / "site"
    site_dir.mkdir(exist_ok=True)
    write_pth(str(site_dir))
    environ = {k: v for k, v in os.environ.items() if not k.startswith("ARMNET_")}
    environ.update(job_env)
    preamble = f"import site, sys; site.addsitedir({str(site_dir)!r}); "
    return subprocess.run([sys.executable, "-c", preamble + code], env=environ, capture_output=True, text=True,
                          timeout=120, check=False)


IN_A_JOB = {env_keys.LEROBOT_TOOLS: "remote", env_keys.CALIBRATION_JOBS: "0"}
RUN_CALIBRATE = ("sys.argv = ['lerobot-calibrate', '--robot.type=so101_follower', '--robot.port=/dev/null', "
                 "'--robot.id=arm']; from lerobot.scripts.lerobot_calibrate import main; main()")


def test_lerobot_calibrate_in_a_job_is_refused_before_it_prompts_saying_the_calibration_is_the_cells(
        tmp_path: Path) -> None:
    done = interpreter(tmp_path, RUN_CALIBRATE, **IN_A_JOB)
    assert done.returncode == 1, done.stderr
    assert CALIBRATE_REFUSAL in done.stderr
    assert "EOFError" not in done.stderr


def test_lerobot_calibrate_runs_on_a_cell_that_allows_calibration_jobs(tmp_path: Path) -> None:
    done = interpreter(tmp_path, RUN_CALIBRATE.replace("'--robot.id=arm'", "'--help'"),
                       **{**IN_A_JOB, env_keys.CALIBRATION_JOBS: "1"})
    assert done.returncode == 0, done.stderr
    assert "--robot.type" in done.stdout and "refused" not in done.stderr


def test_in_a_job_lerobots_bus_is_the_connector_proxy_and_setup_motors_is_refused(tmp_path: Path) -> None:
    code = ("from lerobot.motors.feetech import FeetechMotorsBus; print(FeetechMotorsBus.__module__); "
            "sys.argv = ['lerobot-setup-motors', '--robot.type=so101_follower', '--robot.port=/dev/null']; "
            "from lerobot.scripts.lerobot_setup_motors import main; main()")
    done = interpreter(tmp_path, code, **IN_A_JOB)
    assert done.stdout.split() == ["armnet_runtime.lerobot.remote_feetech"]
    assert done.returncode == 1 and SETUP_MOTORS_REFUSAL in done.stderr


def test_a_local_runs_job_in_the_dev_venv_gets_the_same_start_hook(tmp_path: Path) -> None:
    """The console script as a job's subprocess runs it, with no site directory added by hand."""
    environ = {k: v for k, v in os.environ.items() if not k.startswith("ARMNET_")}
    calibrate = Path(sys.executable).parent / "lerobot-calibrate"
    done = subprocess.run([str(calibrate), "--robot.type=so101_follower", "--robot.port=/dev/null", "--robot.id=arm"],
                          env={**environ, **IN_A_JOB}, capture_output=True, text=True, timeout=120, check=False)
    assert CALIBRATE_REFUSAL in done.stderr, f"no start hook in {sys.prefix}: run scripts/setup.sh\n{done.stderr}"
    assert done.returncode == 1


def test_outside_a_job_lerobot_is_untouched(tmp_path: Path) -> None:
    done = interpreter(tmp_path, "from lerobot.motors.feetech import FeetechMotorsBus; print(FeetechMotorsBus.__module__)")
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["lerobot.motors.feetech.feetech"]


def test_a_connector_started_with_a_jobs_swap_refuses_to_drive_the_bus(tmp_path: Path) -> None:
    code = "from armnet_connector.policed_bus import policed_bus_class; policed_bus_class()"
    done = interpreter(tmp_path, code, **IN_A_JOB)
    assert done.returncode == 1
    assert "belongs to job containers only" in done.stderr
