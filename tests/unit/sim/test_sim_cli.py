"""``armnet sim``: prints the ports, serves until SIGTERM, refuses bad input."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import scservo_sdk as scs

from .test_sim_scservo import txrx

pytestmark = pytest.mark.unit


def armnet(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "armnet_cli.main", "sim", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_sim_prints_the_ports_serves_them_and_stops_on_sigterm(tmp_path: Path) -> None:
    proc = armnet("bimanual_so101", "--json", "--link-dir", str(tmp_path), "--latency-ms", "1")
    try:
        assert proc.stdout is not None
        announced = json.loads(proc.stdout.readline())
        assert announced["preset"] == "bimanual_so101"
        ports = announced["ports"]
        assert ports == {
            "left": str(tmp_path / "bimanual_so101-left"),
            "right": str(tmp_path / "bimanual_so101-right"),
        }
        for port in ports.values():
            handler = scs.PortHandler(port)
            assert handler.openPort()
            try:
                assert txrx(scs.PacketHandler(0).ping, handler, 6) == (777, scs.COMM_SUCCESS, 0)
            finally:
                handler.closePort()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0  # a host busy importing images stalled an exit past 10 s once
        assert not any(tmp_path.iterdir())
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_sim_text_output_names_each_arm() -> None:
    proc = armnet("so101")
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("arm: /dev/pts/")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 0  # a host busy importing images stalled an exit past 10 s once
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_bad_calibration_file_exits_2_with_the_reason(tmp_path: Path) -> None:
    bad = tmp_path / "cal.json"
    bad.write_text("{")
    proc = armnet("so101", "--calibration", str(bad))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert "not JSON" in err and str(bad) in err


def test_calibration_for_an_unknown_arm_is_refused(tmp_path: Path) -> None:
    proc = armnet("bimanual_so101", "--calibration", f"middle={tmp_path / 'x.json'}")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert "middle" in err
