"""The pod launcher lowers a job pod's ``activeDeadlineSeconds`` once its job container runs (real apiserver).

The pod names a node no kubelet serves, so nothing runs it: the test writes the
pod's status as a kubelet would (``startTime``, the job container running since
``startedAt``) through the status subresource, and the launcher's own pod watch
(``PodJob``) reads it and patches the spec.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
from armnet_launch.pod import PodJob
from armnet_launch.pod_spec import active_deadline_seconds, running_deadline_seconds
from kubernetes import client

pytestmark = pytest.mark.integration

TIMEOUT_S, GRACE_S = 60, 3


def _pod(name: str) -> dict[str, Any]:
    return {"apiVersion": "v1", "kind": "Pod", "metadata": {"name": name}, "spec": {
        "nodeName": "no-kubelet-serves-this", "restartPolicy": "Never", "automountServiceAccountToken": False,
        "activeDeadlineSeconds": active_deadline_seconds(TIMEOUT_S, GRACE_S),
        "containers": [{"name": "job", "image": "localhost/armnet-test:dev"}],
    }}


def _deadline(core: Any, ns: str, name: str) -> int:
    return int(core.read_namespaced_pod(name, ns).spec.active_deadline_seconds)


def test_the_deadline_is_lowered_to_the_jobs_own_window_once_its_container_runs(k8s: Any) -> None:
    ns = k8s.create_namespace("pod-deadline")
    core = client.CoreV1Api(k8s.api_client())
    core.create_namespaced_pod(ns, _pod("job-pod"))
    job = PodJob(core, ns, "job-pod", poll_s=0.1,
                 running_deadline=lambda delay: running_deadline_seconds(TIMEOUT_S, GRACE_S, delay))
    try:
        time.sleep(0.5)  # not started yet: the start allowance stands
        assert _deadline(core, ns, "job-pod") == active_deadline_seconds(TIMEOUT_S, GRACE_S)
        core.patch_namespaced_pod_status("job-pod", ns, {"status": {
            "phase": "Running", "startTime": "2026-11-25T06:00:00Z",
            "containerStatuses": [{"name": "job", "image": "localhost/armnet-test:dev", "imageID": "", "ready": True,
                                   "restartCount": 0, "state": {"running": {"startedAt": "2026-11-25T06:00:41Z"}}}],
        }})
        assert job.wait_started(20)
        assert _deadline(core, ns, "job-pod") == running_deadline_seconds(TIMEOUT_S, GRACE_S, 41.0) == 41 + 63 + 30
    finally:
        job.delete(grace_seconds=0)
        k8s.delete_namespace(ns)
