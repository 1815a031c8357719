"""Cells and RobotJobs for the FMS tests, and the RBAC the FMS's ServiceAccount gets (as the chart should)."""

from __future__ import annotations

from typing import Any

import yaml
from armnet_core.api import API_VERSION, CELLS, GROUP, ROBOTJOBS, SITE_LABEL, VERSION

#: What `armnet fms` needs from the API, no more: the chart's ClusterRole should match.
FMS_RULES = [
    {"apiGroups": [GROUP], "resources": ["cells"], "verbs": ["get", "list", "watch", "patch"]},
    {"apiGroups": [GROUP], "resources": ["robotjobs"], "verbs": ["get", "list", "watch", "patch"]},
    {"apiGroups": [""], "resources": ["events"], "verbs": ["create"]},
]


def grant_fms(k8s: Any, user: str) -> None:
    k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump_all([
        {"apiVersion": "rbac.authorization.k8s.io/v1", "kind": "ClusterRole",
         "metadata": {"name": "armnet-fms"}, "rules": FMS_RULES},
        {"apiVersion": "rbac.authorization.k8s.io/v1", "kind": "ClusterRoleBinding",
         "metadata": {"name": f"armnet-fms-{user}"},
         "roleRef": {"apiGroup": "rbac.authorization.k8s.io", "kind": "ClusterRole", "name": "armnet-fms"},
         "subjects": [{"kind": "User", "name": user, "apiGroup": "rbac.authorization.k8s.io"}]},
    ]))


def _api(k8s: Any) -> Any:
    from kubernetes import client

    return client.CustomObjectsApi(k8s.api_client()), client.CoreV1Api(k8s.api_client())


def apply(k8s: Any, obj: dict[str, Any]) -> dict[str, Any]:
    """Create the Cell or RobotJob (through the API, not kubectl: a process per call is slow on a busy machine)."""
    custom, _ = _api(k8s)
    if obj["kind"] == "Cell":
        return dict(custom.create_cluster_custom_object(GROUP, VERSION, CELLS, obj))
    return dict(custom.create_namespaced_custom_object(GROUP, VERSION, obj["metadata"]["namespace"], ROBOTJOBS, obj))


def patch_status(k8s: Any, kind: str, name: str, status: dict[str, Any], namespace: str | None = None) -> None:
    custom, _ = _api(k8s)
    if kind == "cell":
        custom.patch_cluster_custom_object_status(GROUP, VERSION, CELLS, name, {"status": status})
    else:
        custom.patch_namespaced_custom_object_status(GROUP, VERSION, namespace, ROBOTJOBS, name, {"status": status})


def get(k8s: Any, kind: str, name: str, namespace: str | None = None) -> dict[str, Any]:
    custom, _ = _api(k8s)
    if kind == "cell":
        return dict(custom.get_cluster_custom_object(GROUP, VERSION, CELLS, name))
    return dict(custom.get_namespaced_custom_object(GROUP, VERSION, namespace, ROBOTJOBS, name))


def events_about(k8s: Any, namespace: str, name: str) -> list[dict[str, Any]]:
    _, core = _api(k8s)
    items = core.api_client.sanitize_for_serialization(core.list_namespaced_event(namespace).items)
    return [e for e in items if e["involvedObject"]["name"] == name]


def a_cell(name: str, *, site: str = "lab-1", reset_timeout: int = 30) -> dict[str, Any]:
    return {"apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": name, "labels": {SITE_LABEL: site}},
            "spec": {"nodeName": "fms-node", "simulated": True, "embodiment": "lerobot/so-101", "task": "fms",
                     "robot": {"robotId": f"{name}-arm", "safetyLimit": 10}, "resetTimeoutSeconds": reset_timeout}}


def a_job(name: str, namespace: str) -> dict[str, Any]:
    return {"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": name, "namespace": namespace},
            "spec": {"image": "localhost/tenant-image:1", "embodiment": "lerobot/so-101", "task": "fms",
                     "args": {"api_key": "tenant-secret-arg"}}}


def running_on(k8s: Any, cell: str, job: dict[str, Any], *, rollout: dict[str, int] | None = None) -> str:
    """Write the statuses the operator and agent would: the job running on the cell. Returns the job id."""
    meta = job["metadata"]
    job_id = meta["uid"]
    now = "2030-01-01T00:00:00Z"
    status: dict[str, Any] = {"phase": "running", "cellName": cell, "jobId": job_id, "startedAt": now,
                              "progress": "evaluating the policy"}
    if rollout:
        status["rollout"] = rollout
    patch_status(k8s, "robotjob", meta["name"], status, meta["namespace"])
    return str(job_id)


def cell_busy(k8s: Any, cell: str, job_key: str, *, heartbeat: str) -> None:
    conditions = [{"type": t, "status": "True", "reason": "Ok", "lastTransitionTime": heartbeat}
                  for t in ("AgentConnected", "HardwareReady", "CalibrationPresent", "InterlockClear")]
    conditions.append({"type": "CamerasReady", "status": "False", "reason": "NoFrames",
                       "message": "camera front gave no frame", "lastTransitionTime": heartbeat})
    patch_status(k8s, "cell", cell, {"phase": "Busy", "currentJob": job_key, "lastHeartbeatTime": heartbeat,
                                     "conditions": conditions})
