"""A device loss ends a job ``failed`` only when the job's own end was not already under way."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from armnet_node.metrics import AgentMetrics
from armnet_node.model import parse_cell, parse_job
from armnet_node.plan import HostPaths
from armnet_node.runner import JobRunner, RunnerDeps

pytestmark = pytest.mark.unit

LOST = "device lost: arm arm's serial port: /dev/serial/by-id/usb-arm does not exist"


def runner(tmp_path: Path) -> JobRunner:
    """A runner not started: the loss bookkeeping needs no engine and no API server."""
    cell: dict[str, Any] = {"metadata": {"name": "cell-1", "resourceVersion": "7"},
                            "spec": {"embodiment": "lerobot/so-101", "nodeName": "host-1", "simulated": True,
                                     "task": "pick", "robot": {"robotId": "follower-1", "safetyLimit": 7.5}},
                            "status": {"currentJob": "team-a/job-1"}}
    job: dict[str, Any] = {"metadata": {"name": "job-1", "namespace": "team-a", "uid": "uid-1", "resourceVersion": "9"},
                           "spec": {"image": "localhost/pick:1", "embodiment": "lerobot/so-101", "timeoutSeconds": 60},
                           "status": {"phase": "running", "cellName": "cell-1"}}
    deps = RunnerDeps(kube=None, launcher=None, paths=HostPaths(tmp_path), metrics=AgentMetrics(),
                      link=None, uploads=None)
    return JobRunner(parse_job(job), parse_cell(cell), None, deps)


def test_a_device_loss_while_the_job_runs_is_recorded_and_stops_it_gracefully(tmp_path: Path) -> None:
    job = runner(tmp_path)
    job.stop_device_lost(LOST)
    assert job.device_lost == LOST and job.hooks.cancel_gracefully.is_set()


def test_a_device_loss_after_a_user_cancel_began_is_not_recorded(tmp_path: Path) -> None:
    job = runner(tmp_path)
    job.stop()
    job.stop_device_lost(LOST)
    assert job.device_lost is None  # the job ends cancelled, as the cancel said


def test_a_device_loss_after_the_timeouts_grace_window_opened_is_not_recorded(tmp_path: Path) -> None:
    job = runner(tmp_path)
    job.hooks.on_deadline()  # what supervise calls at the deadline
    job.stop_device_lost(LOST)
    assert job.device_lost is None and not job.hooks.cancel_gracefully.is_set()


def test_a_device_loss_after_the_job_ended_does_not_change_its_result(tmp_path: Path) -> None:
    job = runner(tmp_path)
    assert job.settle_device_loss() is None  # supervise returned: the job exited 0, say
    job.stop_device_lost(LOST)
    assert job.device_lost is None


def test_the_loss_recorded_before_the_job_ended_is_the_one_settled(tmp_path: Path) -> None:
    job = runner(tmp_path)
    job.stop_device_lost(LOST)
    job.stop()  # a cancel after the loss: the loss stands
    assert job.settle_device_loss() == LOST
