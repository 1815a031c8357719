"""The venv the suite runs in is the lock's (scripts/setup.d/10-python.sh installs lock/dev.txt).

``pip check`` is clean but for the exceptions lock/overrides.txt declares, every locked
package is installed at its locked version, and LeRobot's own commands start: they import
what LeRobot's pins bring (imageio, gymnasium, rerun, ...), which a ``--no-deps`` install
of LeRobot would leave out. Every module of the venv has its bytecode: setup compiles it,
since no process of the suite writes any where PYTHONDONTWRITEBYTECODE is set.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from armnet_testbed.lockfile import OVERRIDES, lock_file, normalize, overridden, pins, unexcused

pytestmark = pytest.mark.unit

RERUN_SETUP = "the venv is not the lock's: run scripts/setup.sh"


def test_pip_check_finds_no_conflict_but_the_declared_exceptions() -> None:
    result = subprocess.run([sys.executable, "-m", "pip", "check", "--disable-pip-version-check"],
                            capture_output=True, text=True, check=False)

    assert unexcused(result.stdout + result.stderr, overridden(OVERRIDES.read_text())) == [], RERUN_SETUP


def test_every_module_of_the_venv_has_its_bytecode_but_those_this_python_cannot_compile() -> None:
    site = Path(sysconfig.get_paths()["purelib"])
    without = [source for source in site.rglob("*.py")
               if not Path(importlib.util.cache_from_source(str(source))).exists()]

    def compiles(source: Path) -> bool:
        try:
            compile(source.read_bytes(), str(source), "exec")
        except SyntaxError:  # e.g. torch's test module in a newer Python's syntax
            return False
        return True

    assert [str(source.relative_to(site)) for source in without if compiles(source)] == [], RERUN_SETUP
    assert len(without) < 10, without  # the few modules in another Python's syntax, never imported


def test_every_locked_package_is_installed_at_its_locked_version() -> None:
    installed = {normalize(d.metadata["Name"]): d.version for d in importlib.metadata.distributions()}

    wrong = {name: (version, installed.get(name))
             for name, version in pins(lock_file("dev").read_text()).items()
             if installed.get(name) != version}

    assert wrong == {}, RERUN_SETUP


RECORDING_COMMANDS = ("lerobot-record", "lerobot-replay")
USAGE_OF_EACH = """
import contextlib, importlib.metadata, io, json, sys
out = {}
for command in sys.argv[1:]:
    (entry,) = importlib.metadata.entry_points(group="console_scripts", name=command)
    sys.argv = [command, "--help"]
    stdout = io.StringIO()
    code = 0
    with contextlib.redirect_stdout(stdout):
        try:
            entry.load()()
        except SystemExit as exc:
            code = exc.code or 0
    out[command] = {"code": code, "stdout": stdout.getvalue(), "target": entry.value}
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def recording_usage() -> dict[str, dict[str, object]]:
    """Each recording command's ``--help``, run through its console-script entry point.

    One interpreter for both: most of their cost is importing LeRobot (torch, datasets,
    the policies), which the two share; the installed scripts call the same entry points.
    """
    result = subprocess.run([sys.executable, "-c", USAGE_OF_EACH, *RECORDING_COMMANDS],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    usage: dict[str, dict[str, object]] = json.loads(result.stdout.splitlines()[-1])
    return usage


@pytest.mark.parametrize("command", RECORDING_COMMANDS)
def test_lerobots_recording_commands_start_and_print_their_usage(
    command: str, recording_usage: dict[str, dict[str, object]]
) -> None:
    script = Path(sys.executable).parent / command
    usage = recording_usage[command]

    assert script.is_file() and f"{usage['target']}".split(":")[0] in script.read_text()
    assert usage["code"] == 0
    stdout = str(usage["stdout"])
    assert stdout.startswith(f"usage: {command}")
    assert "--robot.type" in stdout and "so101_follower" in stdout
