"""The pod launcher lowers a job pod's ``activeDeadlineSeconds`` once its job container runs (real apiserver).

The pod names a node no kubelet serves, so nothing runs it: the test writes the
pod's status as a kubelet would (``startTime``, the job container running since
``startedAt``) through the status subresource, and the launcher's own pod watch
(``PodJob``) reads it and patches the spec.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest
from armnet_launch.pod import RECORD_MARGIN_S, PodJob, record_wait_s
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


def test_the_wait_for_a_job_container_lasts_while_the_pod_is_pending_and_a_stop_ends_the_pod(k8s: Any) -> None:
    """A pod still starting (a busy node, a long image pull) is waited for, not timed: the job's clock
    starts with its code. A stop request ends the wait and the pod (a job that never ran has nothing to save)."""
    ns = k8s.create_namespace("pod-start-wait")
    core = client.CoreV1Api(k8s.api_client())
    core.create_namespaced_pod(ns, _pod("pending-pod"))
    job = PodJob(core, ns, "pending-pod", poll_s=0.1)
    stop_at = time.monotonic() + 3
    try:
        why = job.wait_for_job_container(lambda: time.monotonic() > stop_at, bound_s=600, poll_s=0.2)
        assert why == "the job was stopped before its container started"
        assert time.monotonic() >= stop_at  # pending all along: the wait did not give up by itself
        assert _deadline(core, ns, "pending-pod") == 1  # the kubelet ends the pod at once
    finally:
        job.delete(grace_seconds=0)
        k8s.delete_namespace(ns)


def test_the_wait_for_a_job_container_ends_when_it_runs_and_past_its_bound_ends_the_pod(k8s: Any) -> None:
    ns = k8s.create_namespace("pod-start-bound")
    core = client.CoreV1Api(k8s.api_client())
    for name in ("starts", "never-starts"):
        core.create_namespaced_pod(ns, _pod(name))
    starts, never = PodJob(core, ns, "starts", poll_s=0.1), PodJob(core, ns, "never-starts", poll_s=0.1)
    try:
        core.patch_namespaced_pod_status("starts", ns, {"status": {
            "phase": "Running", "startTime": "2026-11-25T06:00:00Z",
            "containerStatuses": [{"name": "job", "image": "localhost/armnet-test:dev", "imageID": "", "ready": True,
                                   "restartCount": 0, "state": {"running": {"startedAt": "2026-11-25T06:00:41Z"}}}],
        }})
        assert starts.wait_for_job_container(lambda: False, bound_s=60, poll_s=0.2) is None
        assert never.wait_for_job_container(lambda: False, bound_s=1, poll_s=0.2) == \
            "its container had not started after 1 s"
        assert _deadline(core, ns, "never-starts") == 1
    finally:
        for handle in (starts, never):
            handle.delete(grace_seconds=0)
        k8s.delete_namespace(ns)


def test_the_connectors_record_is_waited_for_until_the_sidecar_stops_not_for_a_fixed_time(k8s: Any) -> None:
    """After the job container exits, the kubelet stops the sidecar (which prints its record then):
    the agent reads the record when the connector's exit shows, however long a busy node takes
    within the pod's termination grace (a fixed 20 s lost the record of a loaded run)."""
    ns = k8s.create_namespace("pod-record-wait")
    core = client.CoreV1Api(k8s.api_client())
    pod = _pod("job-ended")
    pod["spec"]["terminationGracePeriodSeconds"] = 40
    pod["spec"]["initContainers"] = [{"name": "connector", "image": "localhost/armnet-test:dev",
                                      "restartPolicy": "Always"}]
    core.create_namespaced_pod(ns, pod)

    def sidecar(state: dict[str, Any]) -> dict[str, Any]:
        return {"status": {
            "phase": "Running", "startTime": "2026-11-25T06:00:00Z",
            "initContainerStatuses": [{"name": "connector", "image": "localhost/armnet-test:dev", "imageID": "",
                                       "ready": True, "restartCount": 0, "state": state}],
            "containerStatuses": [{"name": "job", "image": "localhost/armnet-test:dev", "imageID": "", "ready": False,
                                   "restartCount": 0, "state": {"terminated": {"exitCode": 0}}}],
        }}

    core.patch_namespaced_pod_status("job-ended", ns, sidecar({"running": {"startedAt": "2026-11-25T06:00:01Z"}}))
    job = PodJob(core, ns, "job-ended", poll_s=0.1)
    try:
        assert job.wait(30) == 0
        stops_at = time.monotonic() + 4
        threading.Timer(4, lambda: core.patch_namespaced_pod_status(
            "job-ended", ns, sidecar({"terminated": {"exitCode": 0}}))).start()
        assert job.connector_record() is None  # no kubelet serves the log: no record to read
        waited = time.monotonic()
        assert waited >= stops_at  # the running sidecar was waited for...
        assert waited < stops_at + 10  # ...until its exit showed, not to the bound (40 + 60 s)
        assert record_wait_s(job.last_pod) == 40 + RECORD_MARGIN_S
    finally:
        job.delete(grace_seconds=0)
        k8s.delete_namespace(ns)
