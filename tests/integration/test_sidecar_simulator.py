"""The connector sidecar runs a simulated cell's simulator itself when the agent cannot hand it ptys.

An agent that runs in a pod (the Helm chart) creates its simulator's ptys in its
own container's ``/dev/pts``; no other container can mount them. The job pod's
sidecar then runs the simulator next to the connector. Real parts: the sidecar's
own entrypoint as a process, the real simulator and connector, the config the pod
launcher renders for it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from armnet_launch.pod_spec import SIDECAR_ENV, device_path
from armnet_launch.sidecar import STARTED_MARKER, SidecarConfig, parse_record
from armnet_sim.calibration import builtin_calibration, dump_calibration

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def sidecar_config(run_dir: Path) -> SidecarConfig:
    calibration_file = run_dir / "calibration" / "arm.json"
    connector = {"arms": {"arm": {"port": device_path("arm"), "calibration_file": str(calibration_file),
                                  "robot_id": "sim-arm", "safety_limit": 10}},
                 "cameras": {}, "simulated": True, "timeout_seconds": 60}
    calibration = {str(calibration_file): json.loads(dump_calibration(builtin_calibration("so101")))}
    return SidecarConfig(connector, str(run_dir / "sockets"), calibration, {"preset": "so101", "latency_ms": 0.0})


def test_the_sidecar_serves_the_connector_on_its_own_simulator_and_confirms_torque_off_at_stop() -> None:
    run_dir = Path(tempfile.mkdtemp(prefix="armnet-sidecar-"))
    config = sidecar_config(run_dir)
    env = {**os.environ, SIDECAR_ENV: json.dumps(config.as_data())}
    process = subprocess.Popen([sys.executable, "-m", "armnet_launch.sidecar"], env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 90
        while not (run_dir / "sockets" / "robot.sock").exists():
            assert process.poll() is None, process.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "the sidecar did not serve robot.sock within 90 s"
            time.sleep(0.2)
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    record = parse_record(out)
    assert record is not None, err[-3000:]
    # The connector's release read the torque back from the simulated servos: the simulator answered.
    assert record["safety"]["torqueOffConfirmed"] == {"arm": True}, err[-3000:]
    assert record["trip_reason"] is None


def catches_sigterm(pid: int) -> bool:
    """The process has a handler for SIGTERM (its ``SigCgt`` mask in ``/proc``)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & (1 << (signal.SIGTERM - 1)))
    return False


def test_a_restarted_sidecar_stopped_while_it_starts_still_leaves_its_tripped_record() -> None:
    # The job can end while a restarted sidecar is still importing (a loaded node): the kubelet's
    # SIGTERM then comes first thing, and the agent needs the record to say why the job failed.
    run_dir = Path(tempfile.mkdtemp(prefix="armnet-sidecar-"))
    config = sidecar_config(run_dir)
    (run_dir / "sockets").mkdir(parents=True)
    (run_dir / "sockets" / STARTED_MARKER).touch()  # an earlier instance ran in this pod
    env = {**os.environ, SIDECAR_ENV: json.dumps(config.as_data())}
    process = subprocess.Popen([sys.executable, "-m", "armnet_launch.sidecar"], env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not catches_sigterm(process.pid):
            assert process.poll() is None, process.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "the sidecar installed no SIGTERM handler within 60 s"
            time.sleep(0.005)
        assert not (run_dir / "sockets" / "robot.sock").exists()
        process.send_signal(signal.SIGTERM)  # as soon as it can be caught: before robot.sock is served
        out, err = process.communicate(timeout=90)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, err[-3000:]
    record = parse_record(out)
    assert record is not None, err[-3000:]
    assert record["restarted"] is True and record["trip_reason"] == "agent_restarted", record
