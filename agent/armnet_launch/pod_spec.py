"""A job as a Kubernetes pod: the customer container and the connector as a native sidecar. Pure.

The pod launcher (``launch.pod``) turns a launch plan into this manifest and
creates it; nothing here talks to the API. The shape is the security contract
of a job on a robot host, so each choice is deliberate:

- the connector is an init container with ``restartPolicy: Always`` (a native
  sidecar) whose ``postStart`` hook returns only once its ``robot.sock`` serves:
  the kubelet runs the hook inside the sync that starts the sidecar and starts
  the customer container only after it (``serving_gate``);
- the sockets (and the camera frame areas the connector keeps beside them) live
  in an ``emptyDir`` with ``medium: Memory`` shared by both containers; the
  calibration the connector writes is another ``emptyDir``, read-only for the job;
- the connector's read-only observer socket (telemetry and rollout events for the
  agent, which reaches it on the host) is in an ``emptyDir`` of the connector only:
  the tenant shares the sockets volume and the network namespace, never this;
- devices (the cell's serial ports and cameras) reach the connector only: it
  requests the cell's extended resource (``armnet.io/cell-<cell>``, served by
  the agent's device plugin, ``deviceplugin``), whose allocation gives them; or,
  without the plugin, ``hostPath`` CharDevice volumes mounted into it alone. The
  customer container requests nothing and sees neither serial devices nor cameras;
- the connector runs as a non-root user the pod names (``CONNECTOR_USER``),
  whatever its image's USER, with every capability dropped;
- the customer container runs as a non-root user, without privilege
  escalation, capabilities or host namespaces, with a read-only root
  filesystem (``/tmp`` is an ``emptyDir``), and no service-account token;
- Secrets reach it as ``secretKeyRef`` env vars: the agent never copies a
  value into the spec;
- ``activeDeadlineSeconds`` is the backstop that ends the pod even if the
  agent is gone: the kubelet counts it from the pod's start, image pulls
  included, so it starts with room for a slow start (``START_ALLOWANCE_S``)
  and the agent lowers it to timeout + grace + margin from the job
  container's own start once that runs (``running_deadline_seconds``; the
  API lets the field only decrease); ``restartPolicy: Never``;
- an owner reference to the RobotJob, so deleting the job collects the pod.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from armnet_core.api import API_VERSION, JOB_ANNOTATION, TIMEOUT_ANNOTATION

from armnet_launch.plan import LABEL_CELL, LABEL_NAME, LABEL_NAMESPACE

CONNECTOR_CONTAINER = "connector"
JOB_CONTAINER = "job"
#: Env var carrying the sidecar's whole configuration (``launch.sidecar``).
SIDECAR_ENV = "ARMNET_SIDECAR"
ANNOTATION_JOB = JOB_ANNOTATION
ANNOTATION_CELL = LABEL_CELL  # the same key: the pod carries its cell as a label and an annotation
ANNOTATION_TIMEOUT = TIMEOUT_ANNOTATION
#: Seconds beyond timeout + grace before the kubelet's own deadline ends the pod.
DEADLINE_MARGIN_S = 30
#: Seconds a pod may take to start its job container (pulling a multi-GB runtime image over a
#: slow link, the connector's start) before the backstop counts against the job: the kubelet
#: counts ``activeDeadlineSeconds`` from the pod's start, the job's timeout from its own.
START_ALLOWANCE_S = 900
#: Seconds the connector gets on SIGTERM to turn torque off and report, beyond the job's grace.
CONNECTOR_STOP_S = 10
#: The customer's user: any non-root id; 65532 is the distroless "nonroot" convention.
JOB_USER = 65532
#: The connector's user: the agent image's own (``armnet``, in dialout/video/plugdev). Set in the
#: pod, not left to the image's USER: ``agent.connectorImage`` may name any image, and a connector
#: image running as root would hold the robot's devices as root. 0 (development stand-ins only)
#: is the one way to a root connector, and it must be asked for (``--connector-user 0``).
CONNECTOR_USER = 65532
SOCKETS_SIZE = "256Mi"
#: The connector's observer socket for the agent: an emptyDir mounted into the connector ONLY (the
#: tenant shares the sockets volume and the network namespace, never this); the agent reaches it on the
#: host under ``<kubelet root>/pods/<pod uid>/volumes/kubernetes.io~empty-dir/observer/``.
OBSERVER_VOLUME = "observer"
#: Where the connector container mounts it.
OBSERVER_DIR = "/run/armnet-observer"
#: The cell's record of the job (``PodInputs.record_dir``): a volume of the connector alone.
RECORD_VOLUME = "cell-record"
TMP_SIZE = "256Mi"
DEVICE_DIR = "/dev/armnet"
CONNECTOR_CPU_REQUEST = "250m"
#: Seconds the connector may take to serve before its start counts as failed (the kubelet then
#: restarts it, and a restarted connector fails the job): a loaded host can take a minute or more
#: to import it.
SERVING_WAIT_S = 300
#: How often the start gate looks for the socket: a fraction of the connector's own start.
SERVING_POLL_S = 0.02


@dataclass(frozen=True)
class SecretRef:
    """One env var of the job taken from a key of a Secret in the job's namespace."""

    env: str
    secret: str
    key: str


@dataclass(frozen=True)
class PodResources:
    """Requests and limits of the customer container (the CRDs carry none yet: agent defaults)."""

    cpu_request: str = "100m"
    memory_request: str = "256Mi"
    cpu_limit: str | None = None
    memory_limit: str | None = "4Gi"

    def as_spec(self) -> dict[str, dict[str, str]]:
        limits = {k: v for k, v in (("cpu", self.cpu_limit), ("memory", self.memory_limit)) if v}
        spec = {"requests": {"cpu": self.cpu_request, "memory": self.memory_request}}
        return {**spec, "limits": limits} if limits else spec


@dataclass(frozen=True)
class PodInputs:
    """Everything the pod of one job is made of; paths are inside the containers."""

    name: str
    namespace: str
    node_name: str
    job_name: str
    job_uid: str
    labels: Mapping[str, str]
    job_image: str
    job_env: Mapping[str, str]
    connector_image: str
    connector_command: tuple[str, ...]
    #: The sidecar's configuration document (``launch.sidecar.SidecarConfig`` as JSON data).
    sidecar: Mapping[str, Any]
    socket_dir: str
    calibration_dir: str
    #: Host directories (persist across jobs): the cell's cache and the namespace's volume.
    cache_dir: str
    volume_dir: str
    timeout_seconds: int
    grace_seconds: float
    job_command: tuple[str, ...] | None = None
    secrets: tuple[SecretRef, ...] = ()
    #: Arm name -> host device path (a serial port or a simulator's pty); the connector's only.
    #: The hostPath fallback: empty when ``device_resource`` is set.
    devices: Mapping[str, str] = field(default_factory=dict)
    #: The cell's extended resource (``armnet.io/cell-<cell>``) the connector requests: the kubelet's
    #: device plugin allocation gives it the devices. None: the ``devices`` hostPath volumes instead.
    device_resource: str | None = None
    resources: PodResources = PodResources()
    #: Development only: host paths mounted read-only at the same path in both containers.
    dev_mounts: tuple[str, ...] = ()
    connector_env: Mapping[str, str] = field(default_factory=dict)
    image_pull_policy: str = "IfNotPresent"
    job_read_only_root: bool = True
    job_user: int = JOB_USER
    connector_user: int = CONNECTOR_USER
    #: Where the connector serves its read-only observer socket for the agent (``OBSERVER_VOLUME``), or None.
    observer_dir: str | None = None
    #: The job's output directory on the host (``ARMNET_OUTPUT_DIR``, uploaded when the job ends), or None.
    output_dir: str | None = None
    #: The cell's record of the job on the host (the rollouts' pictures): the connector's alone, or None.
    record_dir: str | None = None
    #: Host files the connector alone reads, mounted read-only at the same path: the cell's
    #: completion classifier, a judge's token file (``cell_completion.host_files``).
    host_files: tuple[str, ...] = ()


def device_path(arm: str) -> str:
    """Where the connector finds an arm's serial device inside its container."""
    return f"{DEVICE_DIR}/{arm}"


def run_window_seconds(timeout_seconds: int, grace_seconds: float) -> int:
    """The job's own time, counted from its container's start: timeout + grace + margin."""
    return int(timeout_seconds + grace_seconds + 0.999) + DEADLINE_MARGIN_S


def active_deadline_seconds(timeout_seconds: int, grace_seconds: float) -> int:
    """The kubelet's backstop as the pod is created: the run window plus room to start.

    The supervisor ends the job first unless the agent is gone.
    """
    return run_window_seconds(timeout_seconds, grace_seconds) + START_ALLOWANCE_S


def running_deadline_seconds(timeout_seconds: int, grace_seconds: float, job_started_after_s: float) -> int:
    """The backstop once the job container runs, ``job_started_after_s`` after the pod started.

    Both times are the kubelet's (the pod's ``startTime``, the container's
    ``startedAt``), so no clock of the agent's enters; never later than the first.
    """
    tight = int(max(job_started_after_s, 0.0) + 0.999) + run_window_seconds(timeout_seconds, grace_seconds)
    return min(tight, active_deadline_seconds(timeout_seconds, grace_seconds))


def build_pod(inputs: PodInputs) -> dict[str, Any]:
    """The Pod manifest of one job (see the module docstring for why each field is so)."""
    volumes = _volumes(inputs)
    spec: dict[str, Any] = {
        "nodeName": inputs.node_name,
        "restartPolicy": "Never",
        "activeDeadlineSeconds": active_deadline_seconds(inputs.timeout_seconds, inputs.grace_seconds),
        "terminationGracePeriodSeconds": int(inputs.grace_seconds + 0.999) + CONNECTOR_STOP_S,
        "automountServiceAccountToken": False,
        "enableServiceLinks": False,
        "hostNetwork": False,
        "hostPID": False,
        "hostIPC": False,
        # No cluster DNS on a robot host: the node's resolver, no MissingClusterDNS events.
        "dnsPolicy": "Default",
        "securityContext": {"seccompProfile": {"type": "RuntimeDefault"}},
        "initContainers": [_connector(inputs)],
        "containers": [_job(inputs)],
        "volumes": volumes,
    }
    return {
        "apiVersion": "v1",
        "kind": "Pod",
        "metadata": {
            "name": inputs.name,
            "namespace": inputs.namespace,
            "labels": dict(inputs.labels),
            "annotations": {
                ANNOTATION_JOB: f"{inputs.namespace}/{inputs.job_name}",
                ANNOTATION_CELL: inputs.labels.get(LABEL_CELL, ""),
                ANNOTATION_TIMEOUT: str(inputs.timeout_seconds),
            },
            "ownerReferences": [{
                "apiVersion": API_VERSION,
                "kind": "RobotJob",
                "name": inputs.job_name,
                "uid": inputs.job_uid,
                "controller": True,
                "blockOwnerDeletion": False,
            }],
        },
        "spec": spec,
    }


def _probe(socket_path: str, period: int, failures: int) -> dict[str, Any]:
    return {"exec": {"command": ["test", "-S", socket_path]}, "periodSeconds": period,
            "failureThreshold": failures, "timeoutSeconds": 2}


def serving_gate(socket_path: str, wait_s: int = SERVING_WAIT_S, poll_s: float = SERVING_POLL_S) -> list[str]:
    """The sidecar's ``postStart`` command: return once ``socket_path`` serves, fail after ``wait_s``.

    Why a hook and not a startup probe: the kubelet runs a ``postStart`` hook inside the
    sync that starts the container and starts the next container only after the hook
    returned, so the customer container follows the connector's first serving moment
    by one kubelet sync. A startup probe is sampled once per ``periodSeconds`` (one
    second at least) and only after the kubelet's next relist has reported the
    sidecar running: ~1.5 s more on every job start (``bench/dispatch.py``). The
    connector binds ``robot.sock`` only once it serves, so the socket's existence is
    the same readiness a probe checks. A gate that fails makes the kubelet restart the
    connector, which fails the job (a restarted connector never resumes motion).
    """
    tries = max(1, round(wait_s / poll_s))
    script = (f'i=0; until test -S "$1"; do i=$((i+1)); '
              f'if [ "$i" -ge {tries} ]; then echo "the connector did not serve $1 within {wait_s} s" >&2; exit 1; fi; '
              f'sleep {poll_s}; done')
    return ["sh", "-c", script, "serving-gate", socket_path]


def _connector(inputs: PodInputs) -> dict[str, Any]:
    robot_sock = f"{inputs.socket_dir}/robot.sock"
    mounts = [
        {"name": "sockets", "mountPath": inputs.socket_dir},
        {"name": "calibration", "mountPath": inputs.calibration_dir},
        {"name": "connector-tmp", "mountPath": "/tmp"},
        *({"name": f"device-{i}", "mountPath": device_path(arm)} for i, arm in enumerate(_host_devices(inputs))),
        *_dev_mounts(inputs),
        *([{"name": OBSERVER_VOLUME, "mountPath": inputs.observer_dir}] if inputs.observer_dir else []),
        *([{"name": RECORD_VOLUME, "mountPath": inputs.record_dir}] if inputs.record_dir else []),
        *({"name": f"host-file-{i}", "mountPath": path, "readOnly": True} for i, path in enumerate(inputs.host_files)),
    ]
    env = [{"name": SIDECAR_ENV, "value": json.dumps(dict(inputs.sidecar), sort_keys=True)}]
    env += [{"name": k, "value": v} for k, v in sorted(_with_home(inputs.connector_env).items())]
    return {
        "name": CONNECTOR_CONTAINER,
        "image": inputs.connector_image,
        "imagePullPolicy": inputs.image_pull_policy,
        "command": list(inputs.connector_command),
        "restartPolicy": "Always",
        "env": env,
        # The customer container starts only once robot.sock exists (see serving_gate).
        "lifecycle": {"postStart": {"exec": {"command": serving_gate(robot_sock)}}},
        "readinessProbe": _probe(robot_sock, 5, 3),
        # The uid alone, no runAsGroup: the runtime then adds the user's supplementary groups
        # from the image's /etc/group (dialout, video: the devices), as it does for the image's
        # own numeric USER.
        "securityContext": {
            "runAsNonRoot": inputs.connector_user != 0,
            "runAsUser": inputs.connector_user,
            "allowPrivilegeEscalation": False,
            "privileged": False,
            "readOnlyRootFilesystem": True,
            "capabilities": {"drop": ["ALL"]},
        },
        "volumeMounts": mounts,
        # The connector answers bus calls under deadlines: CPU shares above a customer container's.
        "resources": _connector_resources(inputs),
    }


def _connector_resources(inputs: PodInputs) -> dict[str, dict[str, str]]:
    requests = {"cpu": CONNECTOR_CPU_REQUEST, "memory": "256Mi"}
    limits = {"memory": "2Gi"}
    if inputs.device_resource is not None:
        # An extended resource is requested whole, with its limit equal to its request.
        requests[inputs.device_resource] = limits[inputs.device_resource] = "1"
    return {"requests": requests, "limits": limits}


def _job(inputs: PodInputs) -> dict[str, Any]:
    env: list[dict[str, Any]] = [{"name": k, "value": v} for k, v in sorted(_with_home(inputs.job_env).items())]
    env += [
        {"name": ref.env, "valueFrom": {"secretKeyRef": {"name": ref.secret, "key": ref.key}}}
        for ref in sorted(inputs.secrets, key=lambda r: r.env)
    ]
    container: dict[str, Any] = {
        "name": JOB_CONTAINER,
        "image": inputs.job_image,
        "imagePullPolicy": inputs.image_pull_policy,
        "env": env,
        "securityContext": {
            "runAsNonRoot": True,
            "runAsUser": inputs.job_user,
            "runAsGroup": inputs.job_user,
            "allowPrivilegeEscalation": False,
            "privileged": False,
            "readOnlyRootFilesystem": inputs.job_read_only_root,
            "capabilities": {"drop": ["ALL"]},
        },
        "volumeMounts": [
            {"name": "sockets", "mountPath": inputs.socket_dir},
            {"name": "calibration", "mountPath": inputs.calibration_dir, "readOnly": True},
            {"name": "cache", "mountPath": inputs.cache_dir},
            {"name": "volume", "mountPath": inputs.volume_dir},
            {"name": "job-tmp", "mountPath": "/tmp"},
            *([{"name": "output", "mountPath": inputs.output_dir}] if inputs.output_dir else []),
            *_dev_mounts(inputs),
        ],
        "resources": inputs.resources.as_spec(),
    }
    if inputs.job_command is not None:
        container["command"] = list(inputs.job_command)
    return container


def _with_home(env: Mapping[str, str]) -> dict[str, str]:
    """A writable HOME (the root filesystem is read-only and the user has no passwd entry)."""
    return {"HOME": "/tmp", **env}


def _dev_mounts(inputs: PodInputs) -> list[dict[str, Any]]:
    return [{"name": f"dev-{i}", "mountPath": path, "readOnly": True} for i, path in enumerate(inputs.dev_mounts)]


def _host_devices(inputs: PodInputs) -> list[str]:
    """The arms whose device is a hostPath volume: none when the device plugin gives them."""
    return [] if inputs.device_resource is not None else sorted(inputs.devices)


def _volumes(inputs: PodInputs) -> list[dict[str, Any]]:
    volumes: list[dict[str, Any]] = [
        {"name": "sockets", "emptyDir": {"medium": "Memory", "sizeLimit": SOCKETS_SIZE}},
        {"name": "calibration", "emptyDir": {"sizeLimit": "16Mi"}},
        {"name": "job-tmp", "emptyDir": {"sizeLimit": TMP_SIZE}},
        {"name": "connector-tmp", "emptyDir": {"sizeLimit": "64Mi"}},
        {"name": "cache", "hostPath": {"path": inputs.cache_dir, "type": "DirectoryOrCreate"}},
        {"name": "volume", "hostPath": {"path": inputs.volume_dir, "type": "DirectoryOrCreate"}},
    ]
    if inputs.output_dir:
        volumes.append({"name": "output", "hostPath": {"path": inputs.output_dir, "type": "DirectoryOrCreate"}})
    if inputs.observer_dir:
        volumes.append({"name": OBSERVER_VOLUME, "emptyDir": {"medium": "Memory", "sizeLimit": "1Mi"}})
    if inputs.record_dir:
        # Made by the agent and handed to the connector's uid before the pod (the job never mounts it).
        volumes.append({"name": RECORD_VOLUME, "hostPath": {"path": inputs.record_dir, "type": "Directory"}})
    volumes += [
        {"name": f"device-{i}", "hostPath": {"path": inputs.devices[arm], "type": "CharDevice"}}
        for i, arm in enumerate(_host_devices(inputs))
    ]
    volumes += [
        {"name": f"dev-{i}", "hostPath": {"path": path, "type": "Directory"}} for i, path in enumerate(inputs.dev_mounts)
    ]
    # type File: a file missing on the host keeps the pod from starting (the kubelet's FailedMount
    # event names it; the job then ends at its deadline). The cell's CompletionReady condition
    # says so before any job is bound.
    volumes += [
        {"name": f"host-file-{i}", "hostPath": {"path": path, "type": "File"}} for i, path in enumerate(inputs.host_files)
    ]
    return volumes


def pod_identity(labels: Mapping[str, str]) -> tuple[str, str]:
    """``(namespace, name)`` of the RobotJob a pod's labels name."""
    return labels.get(LABEL_NAMESPACE, ""), labels.get(LABEL_NAME, "")
