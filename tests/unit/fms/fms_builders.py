"""Builders for Cells, RobotJobs and reset notices as the FMS lists them."""

from __future__ import annotations

from typing import Any

from armnet_core.api import SITE_LABEL

NOW = 1_800_000_000.0  # a frozen clock
NOW_ISO = "2027-01-15T08:00:00+00:00"


def a_cell(name: str = "so101-a", *, phase: str = "Busy", job: str | None = "team-a/eval-1",
           heartbeat: str | None = NOW_ISO, site: str = "", unschedulable: bool = False,
           interlock: str = "True", reset_timeout: int = 30, extra_conditions: tuple[dict[str, Any], ...] = (),
           queue: dict[str, Any] | None = None) -> dict[str, Any]:
    conditions = [{"type": "AgentConnected", "status": "True", "reason": "Heartbeat"},
                  {"type": "InterlockClear", "status": interlock, "reason": "Tripped" if interlock == "False" else "Clear"},
                  *extra_conditions]
    status: dict[str, Any] = {"phase": phase, "conditions": conditions}
    if job:
        status["currentJob"] = job
    if heartbeat:
        status["lastHeartbeatTime"] = heartbeat
    if queue is not None:
        status["queue"] = queue
    return {"metadata": {"name": name, "uid": f"uid-{name}", "labels": {SITE_LABEL: site} if site else {}},
            "spec": {"embodiment": "so101", "nodeName": "robot-host-1", "unschedulable": unschedulable,
                     "resetTimeoutSeconds": reset_timeout},
            "status": status}


def a_job(namespace: str = "team-a", name: str = "eval-1", *, phase: str = "running", job_id: str = "job-uid-1",
          rollout: dict[str, int] | None = None, progress: str = "",
          rollouts: list[Any] | None = None) -> dict[str, Any]:
    status: dict[str, Any] = {"phase": phase, "jobId": job_id, "cellName": "so101-a"}
    if rollout is not None:
        status["rollout"] = rollout
    if rollouts is not None:
        status["rollouts"] = rollouts
    if progress:
        status["progress"] = progress
    return {"metadata": {"namespace": namespace, "name": name, "uid": job_id},
            "spec": {"image": "tenant/secret-image", "args": {"api_key": "do-not-show"}}, "status": status}


def a_notice(job_id: str = "job-uid-1", at: str = "2027-01-15T07:59:59+00:00") -> dict[str, Any]:
    return {"namespace": "team-a", "job": job_id, "at": at}


def a_rollout(index: int, total: int = 2, *, outcome: str = "unmarked", by: str = "", ended: bool = True,
              monitor: tuple[str, float] | None = None) -> dict[str, Any]:
    """One ``status.rollouts`` entry as the agent writes it; ``monitor``: the monitor's (outcome, score)."""
    row: dict[str, Any] = {"index": index, "total": total, "outcome": outcome, "startedAt": "2027-01-15T07:58:00.000Z"}
    if by:
        row.update(markedBy=by, markedAt="2027-01-15T07:58:30.000Z")
    if monitor is not None:
        row["monitor"] = {"outcome": monitor[0], "score": monitor[1], "at": "2027-01-15T07:58:20.000Z"}
    if ended:
        row["endedAt"] = "2027-01-15T07:59:00.000Z"
    return row
