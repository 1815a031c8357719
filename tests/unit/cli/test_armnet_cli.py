"""The ``armnet`` command: every subcommand is listed and reachable, bad input is refused."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from armnet_cli.main import SUBCOMMANDS

pytestmark = pytest.mark.unit

ARMNET = str(Path(sys.executable).with_name("armnet"))


def run_armnet(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([ARMNET, *args], capture_output=True, text=True, timeout=120, check=False)


def test_help_lists_every_subcommand() -> None:
    result = run_armnet("--help")
    assert result.returncode == 0
    for command in SUBCOMMANDS:
        assert command.name in result.stdout


@pytest.mark.parametrize("command", [c.name for c in SUBCOMMANDS])
def test_each_subcommand_has_its_own_help(command: str) -> None:
    result = run_armnet(command, "--help")
    assert result.returncode == 0, result.stderr
    assert f"armnet {command}" in result.stdout


def test_an_unknown_subcommand_is_a_usage_error() -> None:
    result = run_armnet("teleport")
    assert result.returncode == 2
    assert "invalid choice" in result.stderr
