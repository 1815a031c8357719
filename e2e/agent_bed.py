"""The node agent's e2e test bed: the real apiserver, the real operator and agent processes, Podman.

``AgentBed`` starts ``armnet operator`` and ``armnet agent`` as real processes
(``python -m armnet_cli.main``) against the session's control plane and Podman
API, registers simulated Cells for a node name of its own, and builds tiny job
images from the test bed's base image (the job script copied in, the runtime
taken from this machine's venv and worktree, mounted read-only by the agent's
``--dev-mount``: a development stand-in for a runtime image).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
import uuid
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

import yaml
from armnet_core.api import (
    API_VERSION,
    CELLS,
    GROUP,
    NAMESPACE_LABEL,
    ROBOTJOBS,
    STREAMS_CONNECTED_CONDITION,
    TERMINAL_PHASES,
    VERSION,
)
from armnet_testbed.procs import free_port

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "runtime" / "examples"
#: The job scripts the e2e beds share (each becomes /job/main.py of a job image: ``AgentBed.image``).
JOBS = REPO / "e2e" / "jobs"
PYTHONPATH = ":".join(str(REPO / p) for p in ("runtime/src", "agent", "operator", "cli")) + f":{REPO}"
DEV_MOUNTS = sorted({sys.prefix, sys.base_prefix, str(REPO)})


class AgentBed:
    def __init__(self, k8s: Any, podman: Any, base_image: str, namespace: str, nats_url: str | None = None) -> None:
        self.k8s = k8s
        self.nats_url = nats_url
        self.podman = podman
        self.base_image = base_image
        self.namespace = namespace
        self.node = f"e2e-node-{uuid.uuid4().hex[:6]}"
        self.state_dir = Path(tempfile.mkdtemp(prefix="ag-", dir="/tmp"))
        self.log_dir = Path(tempfile.mkdtemp(prefix="armnet-agent-e2e-logs-"))
        self.operator: subprocess.Popen[bytes] | None = None
        self.agent: subprocess.Popen[bytes] | None = None
        self.metrics_port = free_port()
        self._images: dict[str, str] = {}
        self._agent_starts = 0
        #: Extra ``armnet agent`` arguments (the pod launcher's beds pass ``--launcher pod`` ...).
        self.agent_args: list[str] = []
        #: Extra env of the agent process (the object store's ARMNET_ARTIFACTS_*).
        self.agent_env: dict[str, str] = {}
        self.operator_args: list[str] = []
        #: Extra Containerfile lines for job images (before the COPY).
        self.image_lines: list[str] = []
        #: Called with each job image's tag once built (the pod beds import it into the node).
        self.on_image: Callable[[str], None] | None = None
        self.image_prefix = "armnet-e2e"
        self._objects: Any = None
        #: Publish servo telemetry and camera frames for the cell operator's page. Off unless a
        #: scenario looks at them: every cell's reads and JPEGs cost CPU the other jobs need.
        self.telemetry = False

    def use_pod_launcher(self, node: Any) -> None:
        """Run the jobs as pods on the test bed's node (``armnet agent --launcher pod``), not Podman containers.

        The connector sidecar is the base image with this machine's venv (``--dev-mount``); each
        job image is imported into the node's containerd once built; the cells are the node's.
        """
        self.node = node.name
        # The non-root job user must reach the venv mounted under /root (development stand-in only).
        self.image_lines = ["RUN chmod 0755 /root"]
        self.on_image = node.import_image
        # The stand-in connector image is the bare base image (the venv under /root, 0700 there; the
        # agent's simulator ptys are root's): it runs as root, which the agent does only when told.
        self.agent_args = ["--launcher", "pod", "--connector-image", self.base_image, "--connector-user", "0",
                           "--image-pull-policy", "Never",
                           "--connector-command", f"{sys.executable} -m armnet_launch.sidecar",
                           # The pods' observer sockets, under the test node's own kubelet root.
                           "--kubelet-root-dir", str(node.workdir / "kubelet")]

    # -- processes -----------------------------------------------------------------

    def _env(self) -> dict[str, str]:
        return {**os.environ, "KUBECONFIG": str(self.k8s.kubeconfig), "PYTHONPATH": PYTHONPATH,
                "DOCKER_HOST": self.podman.base_url}

    def start_operator(self) -> None:
        argv = [sys.executable, "-m", "armnet_cli.main", "operator", "--kubeconfig", str(self.k8s.kubeconfig),
                "--namespaces", self.namespace, "--lease-namespace", self.namespace, "--metrics-port", "0",
                "--reconcile-period", "0.5", "--heartbeat-timeout", "15", "--claim-grace", "5", *self.operator_args]
        log = open(self.log_dir / "operator.log", "ab")  # noqa: SIM115 - kept open for the process
        self.operator = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=self._env())

    def start_agent(self) -> None:
        self._agent_starts += 1
        argv = [sys.executable, "-m", "armnet_cli.main", "agent", "--kubeconfig", str(self.k8s.kubeconfig),
                "--node-name", self.node, "--namespaces", self.namespace, "--state-dir", str(self.state_dir),
                "--heartbeat-period", "1", "--pass-period", "0.5", "--metrics-port", str(self.metrics_port),
                "--metrics-address", "127.0.0.1", "--verbose",
                "--dev-env", f"PATH={sys.prefix}/bin:/usr/local/bin:/usr/bin:/bin",
                "--dev-env", f"PYTHONPATH={PYTHONPATH}"]
        for mount in DEV_MOUNTS:
            argv += ["--dev-mount", mount]
        if self.nats_url:
            argv += ["--nats-url", self.nats_url]
        if not self.telemetry:
            argv += ["--telemetry-servo-hz", "0", "--telemetry-frame-fps", "0"]
        argv += self.agent_args
        log = open(self.log_dir / f"agent-{self._agent_starts}.log", "ab")  # noqa: SIM115
        self.agent = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env={**self._env(), **self.agent_env})

    def kill_agent(self) -> None:
        assert self.agent is not None
        self.agent.send_signal(signal.SIGKILL)
        self.agent.wait(10)

    def stop(self) -> None:
        for proc in (self.agent, self.operator):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(15)
                except subprocess.TimeoutExpired:
                    proc.kill()
        for container in self.podman.client.containers.list(
            all=True, filters={"label": f"{NAMESPACE_LABEL}={self.namespace}"}
        ):
            container.remove(force=True)

    def logs(self) -> str:
        return "\n".join(f"== {p.name}\n{p.read_text(errors='replace')[-6000:]}" for p in sorted(self.log_dir.iterdir()))

    # -- objects ----------------------------------------------------------------------

    def apply(self, obj: dict[str, Any], namespaced: bool = True) -> None:
        args = ["apply", "-f", "-"] + (["-n", self.namespace] if namespaced else [])
        self.k8s.kubectl(*args, input=yaml.safe_dump(obj))

    def add_cell(self, name: str, *, bimanual: bool = False, grace: int = 3, **extra: Any) -> str:
        name = f"{name}-{self.node}"
        spec: dict[str, Any] = {"nodeName": self.node, "simulated": True, "gracePeriodSeconds": grace,
                                "resetTimeoutSeconds": 30, "task": self.node}
        if bimanual:
            spec.update(embodiment="lerobot/bimanual_so101", arms={
                "left": {"robotId": "sim_left", "safetyLimit": 10}, "right": {"robotId": "sim_right", "safetyLimit": 10}})
        else:
            spec.update(embodiment="lerobot/so-101", robot={"robotId": f"{name}-arm", "safetyLimit": 10})
        spec.update(extra)
        self.apply({"apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": name}, "spec": spec},
                   namespaced=False)
        return name

    @property
    def objects(self) -> Any:
        """The admin's ``CustomObjectsApi``, made once. Scenarios poll jobs every 0.3 s: through
        ``kubectl`` each read started a process (~70 ms of CPU), ~3 a second beside the suite."""
        if self._objects is None:
            from kubernetes import client

            self._objects = client.CustomObjectsApi(self.k8s.api_client())
        return self._objects

    def cell(self, name: str) -> dict[str, Any]:
        cell: dict[str, Any] = self.objects.get_cluster_custom_object(GROUP, VERSION, CELLS, name)
        return cell

    def job(self, name: str) -> dict[str, Any]:
        job: dict[str, Any] = self.objects.get_namespaced_custom_object(GROUP, VERSION, self.namespace,
                                                                        ROBOTJOBS, name)
        return job

    def job_exists(self, name: str) -> bool:
        from kubernetes.client.exceptions import ApiException

        try:
            self.job(name)
        except ApiException as exc:
            if exc.status == 404:
                return False
            raise
        return True

    def pod(self, name: str) -> dict[str, Any] | None:
        """The pod ``name`` of the bed's namespace as the API serves it (JSON), None if there is none."""
        from kubernetes import client
        from kubernetes.client.exceptions import ApiException

        core = client.CoreV1Api(self.objects.api_client)
        try:
            reply = core.read_namespaced_pod(name, self.namespace, _preload_content=False)
        except ApiException as exc:
            if exc.status == 404:
                return None
            raise
        pod: dict[str, Any] = json.loads(reply.data)
        return pod

    def image(self, name: str, script: str | Path, extra_files: tuple[Path, ...] = ()) -> str:
        """A job image: the base image with the script as /job/main.py (built once per name)."""
        if name in self._images:
            return self._images[name]
        context = Path(tempfile.mkdtemp(prefix="armnet-e2e-image-"))
        source = Path(script).read_text() if isinstance(script, Path) else textwrap.dedent(script)
        (context / "main.py").write_text(source)
        for path in extra_files:
            (context / path.name).write_text(path.read_text())
        (context / "Containerfile").write_text(
            f"FROM {self.base_image}\n" + "".join(f"{line}\n" for line in self.image_lines)
            + "COPY . /job/\nCMD [\"armnet-runtime\", \"/job/main.py\"]\n"
        )
        tag = f"localhost/{self.image_prefix}-{name}:dev"
        self.podman.client.images.build(path=str(context), dockerfile="Containerfile", tag=tag, rm=True)
        if self.on_image is not None:
            self.on_image(tag)
        self._images[name] = tag
        return tag

    def release(self, uid: str) -> None:
        """Let a ``jobs/counts_slowly.py`` job held at its ``hold_at`` line go on (its output dir's ``go``)."""
        (self.state_dir / "outputs" / uid / "go").write_text("")

    def submit(self, name: str, image: str, *, timeout: int = 120, args: dict[str, Any] | None = None,
               embodiment: str = "lerobot/so-101", **spec: Any) -> str:
        body = {"image": image, "embodiment": embodiment, "timeoutSeconds": timeout, "task": self.node,
                "args": args or {}, **spec}
        self.apply({"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": name},
                    "spec": body})
        return name

    def wait(self, predicate: Callable[[], Any], timeout: float, what: str, every: float = 0.3) -> Any:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = predicate()
            if value:
                return value
            time.sleep(every)
        raise AssertionError(f"timed out after {timeout} s waiting for {what}\n{self.logs()}")

    def wait_phase(self, name: str, phases: Collection[str] = TERMINAL_PHASES, timeout: float = 180) -> dict[str, Any]:
        def reached() -> dict[str, Any] | None:
            job = self.job(name)
            return job if (job.get("status") or {}).get("phase") in phases else None
        return self.wait(reached, timeout, f"job {name} to reach {phases}")

    def assert_safety_violation_then_interlock_clears(self, st: dict[str, Any], motor: str = "shoulder_pan") -> None:
        """A job failed by the connector's clamp on ``motor`` (its own record, not the exit code), and
        the cell's InterlockClear comes back once the job is over (a tripped interlock holds for its job only)."""
        assert "safety violation (connector record)" in st["result"]["error"]
        assert motor in st["result"]["error"]
        safety = st["result"]["safety"]
        assert safety["policy"] == "clamp" and safety["interlockTrips"] >= 1
        assert any(r["motor"] == motor for r in safety["refusals"]), safety

        def interlock_clear() -> bool:
            conditions = {c["type"]: c for c in (self.cell(st["cellName"]).get("status") or {}).get("conditions", [])}
            return conditions.get("InterlockClear", {}).get("status") == "True"

        self.wait(interlock_clear, 30, f"InterlockClear on {st['cellName']} after the job")

    def wait_ready(self, cell: str, timeout: float = 60) -> dict[str, Any]:
        seen: dict[str, Any] = {}

        def ready() -> dict[str, Any] | None:
            obj = self.cell(cell)
            status = seen["status"] = obj.get("status") or {}
            conditions = {c["type"]: c["status"] for c in status.get("conditions", [])}
            if self.nats_url is None:  # a bed without NATS: the agent says so, and the cell still runs jobs
                conditions.pop(STREAMS_CONNECTED_CONDITION, None)
            ok = status.get("phase") == "Ready" and len(conditions) >= 5 and set(conditions.values()) == {"True"}
            return obj if ok else None
        try:
            return self.wait(ready, timeout, f"cell {cell} Ready with all health conditions True")
        except AssertionError as failure:
            raise AssertionError(f"{failure}\nthe cell's last status: {seen.get('status')}") from None


class JobWatch:
    """Every RobotJob status the API server reports in one namespace, in order (a watch: no gap between polls).

    What a test cannot read from a job's final status: the phases it went through
    (``queued`` with its reason, before it was dispatched).
    """

    def __init__(self, k8s: Any, namespace: str) -> None:
        from kubernetes import client

        self._api = client.CustomObjectsApi(k8s.api_client())
        self._namespace = namespace
        self._seen: list[tuple[str, dict[str, Any]]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="e2e-job-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from kubernetes import watch

        while not self._stop.is_set():
            stream = watch.Watch()
            try:
                for event in stream.stream(self._api.list_namespaced_custom_object, GROUP, VERSION,
                                           self._namespace, ROBOTJOBS, timeout_seconds=20):
                    obj = event["object"]
                    if event["type"] in ("ADDED", "MODIFIED", "DELETED") and isinstance(obj, dict):
                        with self._lock:
                            self._seen.append((obj["metadata"]["name"], obj.get("status") or {}))
                    if self._stop.is_set():
                        break
            except Exception:  # noqa: BLE001 - a cut watch: list and watch again (duplicates are harmless)
                self._stop.wait(0.5)
            finally:
                stream.stop()

    def statuses(self, name: str) -> list[dict[str, Any]]:
        """The statuses of job ``name`` in the order the API server reported them."""
        with self._lock:
            return [status for seen, status in self._seen if seen == name]

    def close(self) -> None:
        """Stop at the end of the current watch call (no join: that may take its 20 s)."""
        self._stop.set()
