"""Running the job as a Kubernetes pod on this node (the pod launcher's ``LaunchedJob``).

The agent creates the pod ``pod_spec.build_pod`` describes and follows it
through the API server: the customer container's log (the pod log API; it
merges stdout and stderr into one stream, so every line reaches the supervisor
as stdout, which is where the runtime's markers are anyway), its exit code from
the pod status, and the connector sidecar's record line once the pod is done.

Like the container launcher, a followed log may end early (an API server or
kubelet connection cut); once the container has exited, its finished log is
compared with what the follow delivered and the rest is handed on
(``log_recovery``).

Stopping: ``kill()`` lowers the pod's ``activeDeadlineSeconds`` (a field the
API lets only decrease) so the kubelet ends every container now, while the pod
object, its logs and the connector's record stay readable; deleting the pod
would lose them. The pod is deleted by ``remove()`` once the status is written.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from armnet_core.backoff import BackoffPolicy
from armnet_core.times import parse_time

from .log_recovery import DeliveredLines, missed_output
from .pod_spec import CONNECTOR_CONTAINER, JOB_CONTAINER
from .sidecar import parse_record

log = logging.getLogger(__name__)

POLL_S = 0.25
#: Retrying the job container's log follow (not started yet, or the API server blinked).
FOLLOW_RETRY = BackoffPolicy(first_s=0.5, max_s=4.0)
#: How often the wait for the job container's start looks at a stop request and at its bound.
START_POLL_S = 1.0
#: Beyond the pod's own termination grace, how long the kubelet may take to notice the job
#: container's exit, stop the sidecar and publish that in the pod's status (a loaded node
#: took over 20 s, and a record read before the connector printed it is lost).
RECORD_MARGIN_S = 60.0


class PodExists(RuntimeError):
    """A pod of this name exists already (this job's, from a previous agent): adopt it."""


@dataclass(frozen=True)
class ContainerState:
    """One container's state in a pod status, as the launcher needs it."""

    started: bool
    exit_code: int | None
    restarts: int
    reason: str | None = None


def container_state(pod: dict[str, Any], name: str) -> ContainerState:
    """Pure: the state of container ``name`` (init or main) in a pod object (dict form)."""
    status = pod.get("status") or {}
    for entry in (status.get("containerStatuses") or []) + (status.get("initContainerStatuses") or []):
        if entry.get("name") != name:
            continue
        state = entry.get("state") or {}
        terminated = state.get("terminated")
        started = "running" in state or terminated is not None
        exit_code = int(terminated.get("exitCode", -1)) if terminated is not None else None
        waiting = state.get("waiting") or {}
        reason = (terminated or {}).get("reason") or waiting.get("reason")
        return ContainerState(started, exit_code, int(entry.get("restartCount") or 0), reason)
    return ContainerState(False, None, 0)


def job_start_delay_s(pod: dict[str, Any], name: str = JOB_CONTAINER) -> float | None:
    """Pure: seconds from the pod's ``startTime`` to container ``name``'s ``startedAt`` (kubelet times), or None."""
    status = pod.get("status") or {}
    started_pod = parse_time(status.get("startTime"))
    for entry in status.get("containerStatuses") or []:
        if entry.get("name") != name:
            continue
        state = entry.get("state") or {}
        running = state.get("running") or state.get("terminated") or {}
        started_job = parse_time(running.get("startedAt"))
        if started_pod is not None and started_job is not None:
            return max(0.0, (started_job - started_pod).total_seconds())
    return None


def pod_failed_reason(pod: dict[str, Any]) -> str | None:
    """Why a pod ended without its job container running (image missing, deadline, eviction), or None."""
    status = pod.get("status") or {}
    job = container_state(pod, JOB_CONTAINER)
    if job.reason in ("ErrImageNeverPull", "ErrImagePull", "ImagePullBackOff", "InvalidImageName",
                      "CreateContainerConfigError", "CreateContainerError", "RunContainerError"):
        return job.reason
    if status.get("phase") == "Failed" and job.exit_code is None:
        return str(status.get("reason") or status.get("message") or "the pod failed before the job started")
    return None


def record_wait_s(pod: dict[str, Any]) -> float:
    """Pure: how long the connector's record may take to appear once the job container has exited."""
    grace = (pod.get("spec") or {}).get("terminationGracePeriodSeconds")
    return (grace if isinstance(grace, int) and grace >= 0 else 30) + RECORD_MARGIN_S


class PodJob:
    """One job pod; implements the supervisor's ``LaunchedJob``."""

    def __init__(self, core: Any, namespace: str, name: str, *, poll_s: float = POLL_S,
                 on_started: Callable[[float], None] | None = None, follow: bool = True,
                 running_deadline: Callable[[float], int] | None = None) -> None:
        """``follow`` False: a handle for deleting only (no thread polling the pod).

        ``running_deadline`` maps the job container's start delay (seconds after the
        pod's start) to the pod's ``activeDeadlineSeconds`` from then on: the backstop is
        lowered to it once the job runs (``pod_spec.running_deadline_seconds``).
        """
        self._running_deadline = running_deadline
        self._tightened = running_deadline is None
        self._core = core
        self.namespace = namespace
        self.name = name
        self._poll_s = poll_s
        self._on_started = on_started
        self._created_at = time.monotonic()
        self._exit_code: int | None = None
        self._started = threading.Event()
        self._done = threading.Event()
        self._stop = threading.Event()
        self.last_pod: dict[str, Any] = {}
        self.failure: str | None = None
        if follow:
            threading.Thread(target=self._watch, name=f"armnet-pod-{name}", daemon=True).start()

    @classmethod
    def launch(cls, core: Any, manifest: dict[str, Any], **kwargs: Any) -> PodJob:
        """Create the pod; :class:`PodExists` if this job's pod is there already."""
        from kubernetes.client.exceptions import ApiException

        meta = manifest["metadata"]
        try:
            core.create_namespaced_pod(meta["namespace"], manifest)
        except ApiException as exc:
            if exc.status == 409:
                raise PodExists(f"pod {meta['namespace']}/{meta['name']} exists") from exc
            raise
        return cls(core, meta["namespace"], meta["name"], **kwargs)

    @classmethod
    def adopt(cls, core: Any, namespace: str, name: str, **kwargs: Any) -> PodJob:
        """Follow a pod a previous agent process created: its log from the start."""
        return cls(core, namespace, name, **kwargs)

    # -- the pod's state ---------------------------------------------------------------

    def _read(self) -> dict[str, Any] | None:
        from kubernetes.client.exceptions import ApiException

        try:
            pod = self._core.read_namespaced_pod(self.name, self.namespace)
        except ApiException as exc:
            if exc.status == 404:
                return None
            raise
        data: dict[str, Any] = self._core.api_client.sanitize_for_serialization(pod)
        return data

    def _watch(self) -> None:
        """Poll the pod until the job container has exited (or the pod is gone or failed)."""
        while not self._stop.is_set():
            try:
                pod = self._read()
            except Exception:  # noqa: BLE001 - the API server may blink; keep polling
                log.debug("reading pod %s failed", self.name, exc_info=True)
                time.sleep(self._poll_s)
                continue
            if pod is None:
                self.failure = self.failure or "the job's pod was deleted"
                self._finish(-1)
                return
            self.last_pod = pod
            state = container_state(pod, JOB_CONTAINER)
            if state.started and not self._tightened:
                self._tightened = self._tighten_deadline(pod)  # before "started": the agent may go right after
            if state.started and not self._started.is_set():
                self._started.set()
                if self._on_started is not None:
                    self._on_started(time.monotonic() - self._created_at)
            if state.exit_code is not None:
                self._finish(state.exit_code)
                return
            failed = pod_failed_reason(pod)
            if failed is not None:
                self.failure = failed
                self._finish(-1)
                return
            time.sleep(self._poll_s)

    def _tighten_deadline(self, pod: dict[str, Any]) -> bool:
        """Lower the kubelet's backstop to the job's own run window, counted from its container's start.

        True once done (or nothing to do); False to try again on the next poll: a busy API
        server must not leave the pod with its start allowance for the whole job.
        """
        delay = job_start_delay_s(pod)
        if self._running_deadline is None:
            return True
        if delay is None:
            return False
        deadline = self._running_deadline(delay)
        current = (pod.get("spec") or {}).get("activeDeadlineSeconds")
        if isinstance(current, int) and current <= deadline:
            return True  # lowered already (by us before a restart, or by kill())
        try:
            self._core.patch_namespaced_pod(self.name, self.namespace, {"spec": {"activeDeadlineSeconds": deadline}})
        except Exception:  # noqa: BLE001 - tried again on the next poll; the supervisor still times out
            log.warning("lowering the deadline of pod %s to %d s failed; trying again", self.name, deadline,
                        exc_info=True)
            return False
        return True

    def _finish(self, code: int) -> None:
        self._exit_code = code
        self._started.set()
        self._done.set()

    def wait_started(self, timeout: float) -> bool:
        """Until the job container runs (the sidecar served first) or the pod ended; False on timeout."""
        return self._started.wait(timeout)

    def wait_for_job_container(self, stop_requested: Callable[[], bool], bound_s: float,
                               poll_s: float = START_POLL_S) -> str | None:
        """Until the job container runs or the pod ended (a failed pull, the kubelet's deadline, a deletion).

        Ends the pod itself, and says why, when ``stop_requested()`` turns true (a job whose
        code never ran has nothing to save) or after ``bound_s`` (a kubelet that never
        reports); None when the wait ended on its own.
        """
        give_up = time.monotonic() + bound_s
        while not self._started.wait(poll_s):
            if stop_requested():
                self.kill()
                return "the job was stopped before its container started"
            if time.monotonic() > give_up:
                self.kill()
                return f"its container had not started after {bound_s:g} s"
        return None

    @property
    def connector_restarts(self) -> int:
        return container_state(self.last_pod, CONNECTOR_CONTAINER).restarts

    @property
    def oom_killed(self) -> bool:
        return container_state(self.last_pod, JOB_CONTAINER).reason == "OOMKilled"

    # -- LaunchedJob -------------------------------------------------------------------

    def _log(self, follow: bool) -> Any:
        return self._core.read_namespaced_pod_log(
            self.name, self.namespace, container=JOB_CONTAINER, follow=follow, _preload_content=False
        )

    def stdout_chunks(self) -> Iterator[bytes]:
        """The job container's log as it comes, then what the follow missed (``log_recovery``)."""
        self._started.wait()
        delivered = DeliveredLines()
        retry = FOLLOW_RETRY.start()
        while True:
            try:
                response = self._log(follow=True)
            except Exception:  # noqa: BLE001 - not started yet, or the API blinked: retry until the exit
                log.debug("pod log follow of %s failed", self.name, exc_info=True)
                if self._done.wait(retry.failed()):
                    break
                continue
            try:
                for chunk in response.stream(amt=64 * 1024, decode_content=True):
                    delivered.add(chunk)
                    yield chunk
            except Exception:  # noqa: BLE001 - a cut connection: the finished log covers it
                log.debug("pod log follow of %s ended with an error", self.name, exc_info=True)
            finally:
                response.release_conn()
            break
        self._done.wait()
        try:
            finished = self._log(follow=False).data
        except Exception:  # noqa: BLE001 - the pod is gone: the follow is all we have
            log.warning("could not read the finished log of pod %s", self.name, exc_info=True)
            return
        missed = missed_output(finished, delivered)
        if missed:
            log.info("the pod log follow missed %d bytes; delivered from the finished log", len(missed))
            yield missed

    def stderr_chunks(self) -> Iterator[bytes]:
        """Empty: the pod log API merges stderr into the one stream ``stdout_chunks`` reads."""
        return iter(())

    def wait(self, timeout: float) -> int | None:
        return self._exit_code if self._done.wait(max(timeout, 0.0)) else None

    def kill(self) -> None:
        """End every container now, keeping the pod (its logs and the connector's record) readable."""
        try:
            self._core.patch_namespaced_pod(self.name, self.namespace, {"spec": {"activeDeadlineSeconds": 1}})
        except Exception:  # noqa: BLE001 - gone already, or the API refused: delete instead
            log.info("lowering the deadline of pod %s failed; deleting it", self.name, exc_info=True)
            self.delete(grace_seconds=0)

    # -- after the job -------------------------------------------------------------------

    def connector_record(self, wait_s: float | None = None) -> dict[str, Any] | None:
        """The connector's record line, once it has stopped (it prints the line at stop).

        After the job container exits the kubelet stops the sidecar within the pod's
        ``terminationGracePeriodSeconds``; the wait is bounded by that plus
        :data:`RECORD_MARGIN_S` (``wait_s`` overrides), and ends as soon as the connector's
        exit shows in the pod's status: a normal stop is read at once, however busy the node.
        """
        deadline = time.monotonic() + (record_wait_s(self.last_pod) if wait_s is None else wait_s)
        while True:
            try:
                pod = self._read()
            except Exception:  # noqa: BLE001
                pod = self.last_pod
            if pod is None:
                return None
            self.last_pod = pod
            stopped = container_state(pod, CONNECTOR_CONTAINER).exit_code is not None
            ended = (pod.get("status") or {}).get("phase") in ("Succeeded", "Failed")
            if stopped or ended or time.monotonic() > deadline:
                break
            time.sleep(self._poll_s)
        try:
            text = self._core.read_namespaced_pod_log(
                self.name, self.namespace, container=CONNECTOR_CONTAINER, _preload_content=False).data
        except Exception:  # noqa: BLE001 - gone: no record
            return None
        return parse_record(text.decode("utf-8", errors="replace"))

    def delete(self, grace_seconds: int | None = None) -> None:
        from kubernetes.client.exceptions import ApiException

        self._stop.set()
        try:
            self._core.delete_namespaced_pod(self.name, self.namespace, grace_period_seconds=grace_seconds)
        except ApiException as exc:
            if exc.status != 404:
                raise

    def remove(self) -> None:
        self.delete(grace_seconds=0)
