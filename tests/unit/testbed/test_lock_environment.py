"""The venv the suite runs in is the lock's (scripts/setup.d/10-python.sh installs lock/dev.txt).

``pip check`` is clean but for the exceptions lock/overrides.txt declares, every locked
package is installed at its locked version, and LeRobot's own commands start: they import
what LeRobot's pins bring (imageio, gymnasium, rerun, ...), which a ``--no-deps`` install
of LeRobot used to leave out.
"""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
from pathlib import Path

import pytest

from tests.testbed.lockfile import OVERRIDES, lock_file, normalize, overridden, pins, unexcused

pytestmark = pytest.mark.unit

RERUN_SETUP = "the venv is not the lock's: run scripts/setup.sh"


def test_pip_check_finds_no_conflict_but_the_declared_exceptions() -> None:
    result = subprocess.run([sys.executable, "-m", "pip", "check", "--disable-pip-version-check"],
                            capture_output=True, text=True, check=False)

    assert unexcused(result.stdout + result.stderr, overridden(OVERRIDES.read_text())) == [], RERUN_SETUP


def test_every_locked_package_is_installed_at_its_locked_version() -> None:
    installed = {normalize(d.metadata["Name"]): d.version for d in importlib.metadata.distributions()}

    wrong = {name: (version, installed.get(name))
             for name, version in pins(lock_file("dev").read_text()).items()
             if installed.get(name) != version}

    assert wrong == {}, RERUN_SETUP


@pytest.mark.parametrize("command", ["lerobot-record", "lerobot-replay"])
def test_lerobots_recording_commands_start_and_print_their_usage(command: str) -> None:
    script = Path(sys.executable).parent / command

    result = subprocess.run([str(script), "--help"], capture_output=True, text=True, check=False)

    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.startswith(f"usage: {command}")
    assert "--robot.type" in result.stdout and "so101_follower" in result.stdout
