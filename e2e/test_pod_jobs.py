"""Jobs as real Kubernetes pods: ``kubectl apply`` a RobotJob, the agent's pod launcher runs it on the node.

Real kube-apiserver + etcd, the test bed's real node (containerd + kubelet),
the real ``armnet operator`` and ``armnet agent --launcher pod`` processes. The
connector runs as the job pod's native sidecar and reaches the cell simulator's
pty through the agent's device plugin (the sidecar requests the cell's
``armnet.io/cell-<cell>`` resource; the kubelet's allocation bind-mounts the
pty at ``/dev/armnet/<arm>``); the customer container runs non-root and sees no
device. Development stand-in for the images: the base image with
this machine's venv and worktree mounted read-only (``--dev-mount``), like the
container launcher's e2e.

One bed per module: the independent jobs are submitted together and run side
by side on three SO-101 cells and a bimanual one (more jobs than cells: some
wait ``queued``); each test checks its own job. The scenarios that stop the
agent (the kubelet's deadline, the garbage collector) come last.
"""

from __future__ import annotations

import json
import re
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import pytest
from armnet_core.api import API_VERSION, CELL_RESOURCE_PREFIX, GROUP, TERMINAL_PHASES
from armnet_sim.scene_samples import SHIPPED_CLASSIFIER, SHIPPED_CLASSIFIER_INPUT

from e2e import scenarios
from e2e.agent_bed import DEV_MOUNTS, EXAMPLES, JOBS, AgentBed, JobWatch
from e2e.scenarios import explain, moment_of, status

pytestmark = [pytest.mark.node, pytest.mark.e2e, pytest.mark.timeout(900)]

JOB_TIMEOUT = 25

HONOURS_SHUTDOWN = """
    import time
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        ctx.report_progress("watching for shutdown")
        while not ctx.cell.is_shutting_down():
            time.sleep(0.1)
        return {"stopped_cleanly": True}
"""

# What the customer container sees, checked from inside it: the socket was there at its
# first instruction (the sidecar's postStart gate held it back), no serial device, no root.
LOOKS_AROUND = """
    import os
    import stat
    socket_at_start = os.path.exists(os.environ["ARMNET_CELL_SOCKET"].removeprefix("unix://"))
    from armnet_runtime import Context, main

    def char_devices():
        found = []
        for top, dirs, files in os.walk("/dev"):
            for name in files:
                path = os.path.join(top, name)
                try:
                    if stat.S_ISCHR(os.stat(path).st_mode):
                        found.append(path)
                except OSError:
                    pass
        return sorted(found)

    @main
    def run(ctx: Context):
        with open(os.path.join(os.environ["ARMNET_OUTPUT_DIR"], "seen.txt"), "w") as out:  # as the job's user
            out.write("looked around")
        return {"socket_at_start": socket_at_start, "uid": os.getuid(), "devices": char_devices(),
                "secret_length": len(ctx.secrets.get("API_TOKEN", "")),
                "root_writable": os.access("/", os.W_OK)}
"""

# Reads positions, keeps a camera open and runs two rollouts with the operator's buttons, long enough
# for the agent to publish the pod's telemetry; then says which unix sockets it could find anywhere.
# It also tries to forge rollout events the way a tenant could: a connector record on its own output.
OBSERVED = """
    import json
    import os
    import stat
    import time
    from _so101_moves import open_bus
    from armnet_runtime import Context, main
    from lerobot.cameras.opencv import OpenCVCamera

    def sockets(skip):
        found = []
        for top, dirs, files in os.walk("/"):
            if top.startswith(("/proc", "/sys", *skip)):
                dirs[:] = []
                continue
            for name in files:
                try:
                    if stat.S_ISSOCK(os.lstat(os.path.join(top, name)).st_mode):
                        found.append(os.path.join(top, name))
                except OSError:
                    pass
        return sorted(found)

    @main
    def run(ctx: Context):
        # A forged connector record with a rollout of its own: the agent reads the connector's log only.
        forged = {"rollouts": [{"kind": "begin", "at": time.time(), "index": 99, "total": 99}]}
        print("ARMNET_CONNECTOR_RECORD " + json.dumps(forged), flush=True)
        bus = open_bus(ctx.cell.robot_port, ctx.cell.calibration_file_path)
        camera = OpenCVCamera(ctx.camera_configs["front"])
        camera.connect()
        try:
            for index in range(2):
                ctx.cell.rollout_begin(index=index, total=2, outcome_controls=True)
                ctx.report_progress(f"rollout {index}")
                end = time.monotonic() + ctx.args.get("rollout_s", 6)
                while time.monotonic() < end:
                    # A loaded host (CI runs three suites on two cores) starves the sidecar: the
                    # job retries its reads as a LeRobot loop on a busy bus would, and gives a
                    # frame 5 s. What this test checks is telemetry, not latency.
                    bus.sync_read("Present_Position", num_retry=5)
                    camera.async_read(timeout_ms=5000)
                    time.sleep(0.1)
                ctx.cell.rollout_end()
        finally:
            camera.disconnect()
            bus.disconnect(disable_torque=False)
        return {"sockets": sockets(tuple(ctx.args.get("skip", ())))}
"""

SECRET_VALUE = "s3cr3t-pod-value-42"


@pytest.fixture(scope="module")
def pod_outputs(object_store: Any) -> str:
    return str(object_store.create_bucket("pod-e2e-outputs"))


@pytest.fixture(scope="module")
def bed(k8s: Any, k8s_node: Any, podman: Any, base_image: str, nats_server: str, object_store: Any,
        pod_outputs: str) -> Iterator[AgentBed]:
    namespace = k8s.create_namespace("pod-e2e")
    bed = AgentBed(k8s, podman, base_image, namespace, nats_url=nats_server)
    bed.agent_env = object_store.agent_env(pod_outputs)
    bed.use_pod_launcher(k8s_node)
    bed.image_prefix = "armnet-pod-e2e"
    bed.agent_args += ["--telemetry-servo-hz", "2", "--telemetry-frame-fps", "1"]
    bed.telemetry = True
    # The outage tests keep the agent away for a minute or more (a pod's deadline, the garbage
    # collector's sync): the operator must not fail the running job as lost meanwhile (default
    # 15 s heartbeat timeout + 60 s lost grace).
    bed.operator_args = ["--lost-grace", "600"]
    camera = {"front": {"indexOrPath": 0}}
    bed.cells = [bed.add_cell(f"pod-{c}", cameras=camera) for c in "abc"]  # type: ignore[attr-defined]
    bed.bimanual = bed.add_cell("pod-bimanual", bimanual=True)  # type: ignore[attr-defined]
    # An evaluation cell whose monitor runs the learned classifier (a host file the agent allows,
    # --completion-files-dir). This agent runs the simulator itself: a job pod's camera would draw
    # no arm, so the cell must say it cannot be scored rather than take evaluations.
    bed.agent_args += ["--completion-files-dir", str(SHIPPED_CLASSIFIER.parent)]
    bed.evaluator = bed.add_cell(  # type: ignore[attr-defined]
        "pod-eval", task="evaluation", cameras={"front": {"indexOrPath": 0, "width": 640, "height": 480, "fps": 30}},
        completion={"camera": "front", "scorer": "classifier", "consecutiveFrames": 3, "rateHz": 15,
                    "classifier": {"model": str(SHIPPED_CLASSIFIER), "inputSize": SHIPPED_CLASSIFIER_INPUT}})
    bed.start_operator()
    bed.start_agent()
    try:
        for cell in [*bed.cells, bed.bimanual]:  # type: ignore[attr-defined]
            try:
                bed.wait_ready(cell, timeout=180)
            except AssertionError as exc:
                raise AssertionError(f"{json.dumps(bed.cell(cell).get('status'), indent=1)}\n{exc}") from None
        yield bed
    finally:
        bed.stop()
        k8s.kubectl("delete", "pods", "--all", "-n", namespace, "--grace-period=0", "--force", check=False)
        k8s.delete_namespace(namespace)


class TelemetryHeard:
    """Every ``telemetry.>`` message on the bed's NATS from the batch's submission on, with when it arrived."""

    def __init__(self, nats_url: str) -> None:
        import asyncio
        import threading

        self._messages: list[tuple[datetime, str, bytes]] = []
        self._lock = threading.Lock()
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._loop.run_until_complete, args=(self._listen(nats_url),),
                                        daemon=True)
        self._thread.start()
        assert self._ready.wait(30), "the telemetry listener did not connect to NATS"

    async def _listen(self, nats_url: str) -> None:
        import asyncio

        import nats

        client = await nats.connect(nats_url)

        async def keep(msg: Any) -> None:
            with self._lock:
                self._messages.append((datetime.now(UTC), msg.subject, msg.data))

        await client.subscribe("telemetry.>", cb=keep)
        await client.flush()
        self._ready.set()
        self._stop = asyncio.Event()
        await self._stop.wait()
        await client.close()

    def of(self, subject: str) -> list[tuple[datetime, bytes]]:
        with self._lock:
            return [(at, data) for at, s, data in self._messages if s == subject]

    def close(self) -> None:
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)


@pytest.fixture(scope="module")
def telemetry(bed: AgentBed) -> Iterator[TelemetryHeard]:
    assert bed.nats_url is not None
    heard = TelemetryHeard(bed.nats_url)
    yield heard
    heard.close()


@pytest.fixture(scope="module")
def job_watch(bed: AgentBed) -> Iterator[JobWatch]:
    """The phases every job of the bed went through (started before the batch is submitted)."""
    watch = JobWatch(bed.k8s, bed.namespace)
    yield watch
    watch.close()


@pytest.fixture(scope="module")
def batch(bed: AgentBed, telemetry: TelemetryHeard, job_watch: JobWatch) -> dict[str, str]:
    """The independent scenarios' jobs, submitted together so they run side by side.

    Six pods for the three SO-101 cells (the last, ``observed``, waits ``queued`` behind
    three of them) and one for the bimanual cell. The missing secret's job goes first: it
    ends before any pod, so it costs the batch nothing.
    """
    bed.k8s.kubectl("create", "secret", "generic", "api-token", "-n", bed.namespace,
                    f"--from-literal=API_TOKEN={SECRET_VALUE}")
    moves = (EXAMPLES / "_so101_moves.py",)
    # Every image first, then the jobs in one burst: built between submits (minutes on a cold
    # host), the first jobs had ended and freed a cell before ``observed`` was submitted.
    images = {
        "raises": bed.image("raises", JOBS / "raises.py"),
        "bus-loop": bed.image("bus-loop", EXAMPLES / "bus_loop.py", moves),
        "looks-around": bed.image("looks-around", LOOKS_AROUND),
        "unsafe": bed.image("unsafe", JOBS / "unsafe.py", moves),
        "both-arms": bed.image("both-arms", JOBS / "drives_both_arms.py", moves),
        "ignores": bed.image("ignores", JOBS / "ignores_shutdown.py"),
        "observed": bed.image("observed", OBSERVED, moves),
    }
    return {
        # No pod is ever made for it: any image will do.
        "missing-secret": bed.submit("no-secret", images["raises"], secrets={"API_TOKEN": "absent"}),
        "success": bed.submit("bus-loop", images["bus-loop"], timeout=240, args={"degrees": 4}),
        # Generous timeouts: on a loaded host a pod's Python takes a minute or more to import the SDK.
        "failure": bed.submit("raises", images["raises"], timeout=300),
        "shape": bed.submit("looks-around", images["looks-around"], timeout=300, secrets={"API_TOKEN": "api-token"}),
        "safety": bed.submit("unsafe", images["unsafe"], timeout=300),
        "bimanual": bed.submit("bimanual", images["both-arms"], embodiment="lerobot/bimanual_so101", timeout=300),
        "timeout": bed.submit("ignores", images["ignores"], timeout=JOB_TIMEOUT),
        "observed": bed.submit("observed", images["observed"],
                               timeout=300, args={"skip": list(DEV_MOUNTS)}),  # the venv: large, no sockets
    }


def pod_of(bed: AgentBed, job: dict[str, Any]) -> dict[str, Any] | None:
    return bed.pod(f"armnet-{job['metadata']['uid']}")


def test_a_bus_loop_job_in_a_pod_moves_the_arm_through_the_sidecar_and_succeeds(
    bed: AgentBed, batch: dict[str, str], object_store: Any, pod_outputs: str,
) -> None:
    st = scenarios.a_bus_loop_job_succeeds_with_its_return_value(bed, batch["success"])
    assert st["result"]["safety"]["policy"] == "clamp"  # the sidecar's record reached the status
    # The sidecar's servo trace of the job, in the cell's record the agent stored with the output.
    bed.wait(lambda: (status(bed.job(batch["success"])).get("artifacts") or {}).get("phase") == "Uploaded", 120,
             "the pod job's cell record uploaded")
    scenarios.a_bus_loop_job_s_servo_trace_is_stored_and_agrees_with_it(st, object_store, pod_outputs,
                                                                       f"{bed.namespace}/{st['jobId']}/")


def test_a_job_pod_that_raises_fails_with_its_traceback(bed: AgentBed, batch: dict[str, str]) -> None:
    scenarios.a_job_that_raises_fails_with_its_traceback(bed, batch["failure"])


def test_a_missing_secret_fails_the_job_before_it_starts_naming_the_secret_and_no_pod_is_made(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    job = scenarios.a_missing_secret_fails_the_job_before_it_starts(bed, batch["missing-secret"])
    assert pod_of(bed, job) is None


def test_a_safety_violation_in_a_pod_fails_the_job_with_the_sidecars_record_and_the_interlock_clears(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    # The interlock's reason comes from the sidecar connector's record (its log), not from the exit code.
    scenarios.a_safety_violation_fails_the_job_and_the_interlock_clears(bed, batch["safety"], within_s=400)


def test_the_customer_container_starts_after_the_connector_serves_runs_non_root_and_sees_no_device(
    bed: AgentBed, batch: dict[str, str], object_store: Any, pod_outputs: str,
) -> None:
    job = bed.wait_phase(batch["shape"], timeout=300)
    st = status(job)
    assert st["phase"] == "succeeded", explain(st)
    seen = st["result"]["returnValue"]
    assert seen["socket_at_start"] is True
    assert seen["uid"] != 0
    assert not seen["root_writable"]
    # The container's own devpts (/dev/pts/ptmx) and the runtime's defaults are fine; a host pty
    # (/dev/pts/<n>), a serial adapter, a camera or the connector's device path are not.
    host_devices = [d for d in seen["devices"]
                    if d.startswith("/dev/armnet") or re.match(r"/dev/(pts/\d|ttyUSB|ttyACM|ttyS|video)", d)]
    assert not host_devices, seen
    assert seen["secret_length"] == len(SECRET_VALUE)
    assert SECRET_VALUE not in json.dumps(job)
    # What the non-root job wrote to its output directory is stored by the agent.
    bed.wait(lambda: (status(bed.job(batch["shape"])).get("artifacts") or {}).get("phase") == "Uploaded", 120,
             "the pod job's output uploaded")
    key = f"{bed.namespace}/{st['jobId']}/files/seen.txt"
    assert object_store.client().get_object(Bucket=pod_outputs, Key=key)["Body"].read() == b"looked around"


def test_a_job_pod_ignoring_shutdown_is_killed_after_grace_and_ends_timeout(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    # Timeout, the 3 s grace, then the kill and the status write: 35.1 s measured at load ~12 in a
    # clean-clone run (the kubelet's kill, the pod's exit seen, the write), hence 10 s for those.
    scenarios.a_job_ignoring_shutdown_is_killed_at_the_end_of_grace(bed, batch["timeout"], job_timeout=JOB_TIMEOUT,
                                                                    end_seen_s=10)


def test_a_running_job_pod_has_the_sidecar_shape_and_a_cancel_ends_it_cancelled(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    image = bed.image("counts", JOBS / "counts_slowly.py")
    bed.submit("to-cancel", image, args={"lines": 1000, "pause": 0.2}, timeout=300)
    job = bed.wait_phase("to-cancel", ("running",), timeout=300)
    pod = bed.wait(lambda: pod_of(bed, job), 30, "the job's pod")
    spec = pod["spec"]
    connector, = spec["initContainers"]
    customer, = spec["containers"]
    assert connector["restartPolicy"] == "Always" and "postStart" in connector["lifecycle"]
    assert spec["restartPolicy"] == "Never" and spec["automountServiceAccountToken"] is False
    assert spec["activeDeadlineSeconds"] >= 300 + 3
    assert pod["metadata"]["ownerReferences"][0]["uid"] == job["metadata"]["uid"]
    volumes = {v["name"]: v for v in spec["volumes"]}
    # The devices come from the agent's device plugin: the connector requests its cell's resource,
    # the customer container nothing; no hostPath device volume exists.
    resource = f"{CELL_RESOURCE_PREFIX}{job['status']['cellName']}"
    assert connector["resources"]["limits"][resource] == "1"
    assert not [n for section in customer["resources"].values() for n in section if n.startswith(f"{GROUP}/")]
    assert not [v for v in volumes.values() if v.get("hostPath", {}).get("type") == "CharDevice"]
    assert volumes["sockets"]["emptyDir"]["medium"] == "Memory"
    assert customer["securityContext"]["runAsNonRoot"] is True
    assert customer["securityContext"]["allowPrivilegeEscalation"] is False
    started = {s["name"]: s for s in pod["status"].get("initContainerStatuses", [])}
    assert started["connector"]["started"] is True  # its postStart gate returned: robot.sock served
    # Readiness is the kubelet's periodic probe (every 5 s), sampled after the customer container may
    # already run: a job can be "running" a probe period before its sidecar reads ready.
    def connector_ready() -> bool:
        current = pod_of(bed, job) or {}
        statuses = (current.get("status") or {}).get("initContainerStatuses", [])
        return any(s["name"] == "connector" and s.get("ready") is True for s in statuses)
    bed.wait(connector_ready, 30, "the connector sidecar ready (its readiness probe)")

    bed.k8s.kubectl("patch", "rj", "to-cancel", "-n", bed.namespace, "--type=merge", "-p", '{"spec":{"cancel":true}}')
    st = status(bed.wait_phase("to-cancel", timeout=60))
    assert st["phase"] == "cancelled", explain(st)
    bed.wait(lambda: pod_of(bed, job) is None, 30, "the cancelled job's pod removed")


def test_a_cancelled_job_pod_that_honours_shutdown_ends_cancelled_with_its_return_value_within_grace(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    bed.submit("honours-cancel", bed.image("honours", HONOURS_SHUTDOWN), timeout=300)
    bed.wait(lambda: status(bed.job("honours-cancel")).get("progress") == "watching for shutdown", 300,
             "the job pod watching for shutdown")
    bed.k8s.kubectl("patch", "rj", "honours-cancel", "-n", bed.namespace, "--type=merge", "-p",
                    '{"spec":{"cancel":true}}')
    st = status(bed.wait_phase("honours-cancel", timeout=60))
    assert st["phase"] == "cancelled", explain(st)
    # Told through the sidecar's agent.sock (its grace window opened at once), the job returned by itself:
    # a job killed at the end of the 3 s window (the container launcher's path before) has no return value.
    assert st["result"].get("returnValue") == {"stopped_cleanly": True}, explain(st)
    assert st["result"]["exitCode"] == 0, explain(st)
    text = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10).read().decode()
    assert 'armnet_agent_sidecar_inputs_total{op="cancel",result="applied"}' in text


def test_the_agent_exports_the_pod_start_latency(bed: AgentBed, batch: dict[str, str]) -> None:
    bed.wait_phase(batch["failure"], timeout=400)  # launched by this agent process (not restarted yet)
    text = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10).read().decode()
    count = [line for line in text.splitlines() if line.startswith("armnet_agent_pod_start_latency_seconds_count")]
    assert count and float(count[0].split()[-1]) >= 1, count


def test_the_agent_registered_a_healthy_device_plugin_per_cell_and_the_kubelet_allocated_it(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    bed.wait_phase(batch["failure"], timeout=400)  # launched by this agent process (not restarted yet)
    text = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10).read().decode()
    for cell in [*bed.cells, bed.bimanual]:  # type: ignore[attr-defined]
        assert f'armnet_agent_device_plugin_registrations_total{{cell="{cell}",result="ok"}}' in text, cell
        assert f'armnet_agent_device_healthy{{cell="{cell}"}} 1.0' in text, cell
    granted = [line for line in text.splitlines()
               if line.startswith("armnet_agent_device_plugin_allocations_total") and 'result="granted"' in line]
    assert sum(float(line.split()[-1]) for line in granted) >= 1, granted


def test_a_bimanual_job_pod_drives_both_arms_through_its_cells_device_plugin(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    st = scenarios.a_bimanual_job_runs_on_the_bimanual_cell(bed, batch["bimanual"], within_s=400)
    moved = st["result"]["returnValue"]["moved"]
    assert set(moved) == {"left", "right"}, moved
    for arm in moved.values():  # each arm went about 2 degrees out, then back
        assert abs(arm["reached"] - arm["start"]) >= 1.0 and abs(arm["back"] - arm["start"]) <= 1.0, moved
    # Both arms' ptys reached the sidecar through the one allocation of the cell's resource (the
    # connector has no other way to them: no hostPath device volume with the plugin on).
    text = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10).read().decode()
    granted = f'armnet_agent_device_plugin_allocations_total{{cell="{st["cellName"]}",result="granted"}}'
    line = [x for x in text.splitlines() if x.startswith(granted)]
    assert line and float(line[0].split()[-1]) >= 1, line


def test_an_agent_killed_mid_job_readopts_the_pod_and_reports_every_line_once(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    scenarios.an_agent_killed_mid_job_readopts_it_and_reports_every_line_once(bed, lines=40, output_within_s=240)


def test_a_connector_sidecar_killed_mid_job_comes_back_tripped_and_the_job_fails_with_the_reason(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    image = bed.image("counts", JOBS / "counts_slowly.py")
    # Held after line 3 until the sidecar is killed: mid-job however slowly the exec comes.
    bed.submit("loses-connector", image, args={"lines": 40, "pause": 0.25, "hold_at": 3}, timeout=200)
    job = bed.wait_phase("loses-connector", ("running",), timeout=300)

    def some_output() -> bool:
        progress = status(bed.job("loses-connector")).get("progress") or ""
        return progress.startswith("line ") and int(progress.split()[1]) >= 3

    bed.wait(some_output, 240, "some output")
    # SIGTERM to the sidecar's PID 1 (the kernel ignores SIGKILL to a namespace's init from inside it).
    bed.k8s.kubectl("exec", "-n", bed.namespace, f"armnet-{job['metadata']['uid']}", "-c", "connector", "--",
                    "python3", "-c", "import os, signal; os.kill(1, signal.SIGTERM)")

    def connector_back() -> bool:  # restarted and serving again (its postStart gate returned)
        statuses = ((pod_of(bed, job) or {}).get("status") or {}).get("initContainerStatuses", [])
        return any(s["name"] == "connector" and s.get("restartCount", 0) >= 1 and s.get("started") is True
                   for s in statuses)

    bed.wait(connector_back, 240, "the connector sidecar restarted and serving")
    bed.release(job["metadata"]["uid"])
    st = status(bed.wait_phase("loses-connector", timeout=300))
    assert st["phase"] == "failed", explain(st)
    assert "connector sidecar restarted" in st["result"]["error"]
    # The restarted connector's own record: it came back with the interlock tripped.
    assert "connector record: agent_restarted: the connector restarted while the job ran" in st["result"]["error"]


def test_a_monitored_cell_whose_pods_cameras_cannot_see_the_arm_says_so_and_takes_no_job(bed: AgentBed) -> None:
    def completion_ready() -> dict[str, Any] | None:
        conditions = (bed.cell(bed.evaluator).get("status") or {}).get("conditions") or []  # type: ignore[attr-defined]
        return next((c for c in conditions if c["type"] == "CompletionReady"), None)

    condition = bed.wait(completion_ready, 60, "CompletionReady on the monitored cell")
    assert (condition["status"], condition["reason"]) == ("False", "CannotSeeTheArm"), condition
    assert "--pod-simulator sidecar" in condition["message"]
    assert bed.wait(lambda: bed.cell(bed.evaluator).get("status", {}).get("phase") == "Faulted", 60,  # type: ignore[attr-defined]
                    "the operator faulting the cell")


def test_a_job_beyond_the_free_cells_waits_queued_and_runs_once_a_cell_is_free_never_sharing_one(
    bed: AgentBed, batch: dict[str, str], job_watch: JobWatch
) -> None:
    last = batch["observed"]  # the batch's sixth pod for three SO-101 cells
    so101 = [name for key, name in batch.items() if key != "bimanual"]
    finals = {name: status(bed.wait_phase(name, timeout=600)) for name in so101}
    seen = job_watch.statuses(last)
    phases = [s.get("phase") for s in seen]
    assert "queued" in phases and "running" in phases, phases
    assert phases.index("queued") < phases.index("running"), phases
    assert {s.get("queuedReason") for s in seen if s.get("phase") == "queued"} == {"AllCellsBusy"}, seen
    # On each cell one job at a time: a job starts only once the one before it there has finished.
    by_cell: dict[str, list[tuple[datetime, datetime, str]]] = {}
    for name, st in finals.items():
        if "startedAt" in st:  # the missing secret's job never started
            by_cell.setdefault(st["cellName"], []).append(
                (moment_of(st["startedAt"]), moment_of(st["finishedAt"]), name))
    for cell, runs in by_cell.items():
        runs.sort()
        for before, after in zip(runs, runs[1:], strict=False):
            assert before[1] <= after[0], f"{after[2]} started on {cell} before {before[2]} finished: {runs}"
    started = moment_of(finals[last]["startedAt"])
    ahead = [name for _, finished, name in by_cell[finals[last]["cellName"]] if name != last and finished <= started]
    assert ahead, by_cell


def test_a_running_pod_jobs_servo_reads_and_camera_reach_nats_and_its_rollouts_reach_its_status(
    bed: AgentBed, batch: dict[str, str], telemetry: TelemetryHeard
) -> None:
    import cv2
    import numpy as np

    st = status(bed.wait_phase(batch["observed"], timeout=400))
    assert st["phase"] == "succeeded", explain(st)
    cell = st["cellName"]
    # While it ran (between its two rollouts' begin and end): its reads and its camera, from the pod.
    begun, ended = (moment_of(st["rollouts"][0]["startedAt"]), moment_of(st["rollouts"][-1]["endedAt"]))
    readings = [json.loads(data) for at, data in telemetry.of(f"telemetry.{cell}.servos") if begun <= at <= ended]
    from_job = [r for r in readings if r["source"] == "job" and isinstance(r["arms"]["arm"].get("motors"), dict)]
    if not from_job:
        observer = [line for line in bed.logs().splitlines() if "observer" in line]
        pytest.fail(f"no servo reading of the job on {cell}: {readings[-3:]}; the agent on its observer socket: "
                    f"{observer[-5:]}")
    motors = from_job[-1]["arms"]["arm"]["motors"]
    assert all(0 <= m["position"] < 4096 and "load" not in m for m in motors.values()), motors
    frames = [data for at, data in telemetry.of(f"telemetry.{cell}.camera.front") if begun <= at <= ended]
    assert frames and cv2.imdecode(np.frombuffer(frames[-1], np.uint8), cv2.IMREAD_COLOR) is not None
    text = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10).read().decode()
    ok = [line for line in text.splitlines()
          if line.startswith('armnet_agent_sidecar_observer_requests_total{result="ok"}')]
    assert ok and float(ok[0].split()[-1]) > 0, ok

    history = st["rollouts"]
    assert [(r["index"], r["total"], r["outcomeControls"], r["outcome"]) for r in history] == [
        (0, 2, True, "unmarked"), (1, 2, True, "unmarked")]
    assert all("endedAt" in r for r in history), history
    # Neither the forged record's rollout 99 (job output is not the connector's log) nor any socket but
    # the job's own two in the tenant's container: nothing there can pose as the connector.
    found = st["result"]["returnValue"]["sockets"]
    assert found and all(path.rsplit("/", 1)[-1] in ("robot.sock", "operator.sock") for path in found), found


#: The timeout of the job the kubelet ends: the agent is stopped as soon as the job runs, long before this.
#: The pod's deadline is lowered, once the job runs, to this + grace + margin from the job container's start.
OUTLIVES_TIMEOUT = 20


@dataclass
class AgentOutage:
    """The agent SIGKILLed while two jobs run, one for the kubelet's deadline and one for the garbage collector.

    The two scenarios share one outage: the collector's (seconds) fits in the deadline's wait.
    ``restart()`` ends the outage (the last scenario checks what the agent then decides).
    """

    bed: AgentBed
    jobs: dict[str, dict[str, Any]]
    pods: dict[str, dict[str, Any]]
    collector: Any
    restarted: bool = False

    def restart(self) -> None:
        if not self.restarted:
            self.restarted = True
            self.bed.start_agent()


@pytest.fixture(scope="module")
def outage(bed: AgentBed) -> Iterator[AgentOutage]:
    """Both jobs running (their pods start side by side), a garbage collector synced, then the agent killed.

    The collector is the real one: kube-controller-manager with only that controller (the test
    bed runs none). One worker: with ``blockOwnerDeletion`` false, several could drop a
    foreground-deleted RobotJob's finalizer before handling its pod, and then find the owner no
    longer waiting for its dependents.
    """
    from armnet_testbed.controllers import WorkloadControllers

    names = {
        "deadline": bed.submit("outlives", bed.image("ignores", JOBS / "ignores_shutdown.py"),
                               timeout=OUTLIVES_TIMEOUT),
        "collected": bed.submit("collected", bed.image("counts", JOBS / "counts_slowly.py"),
                                args={"lines": 2000, "pause": 0.2}, timeout=300),
    }
    collector = WorkloadControllers(plane=bed.k8s, controllers=("garbage-collector-controller",),
                                    scheduler=False, extra_args=("--concurrent-gc-syncs=1",)).start()
    state = None
    try:
        # The agent is killed as soon as the deadline's job runs (its own kill would come 23 s later):
        # the other job needs its pod only.
        deadline_job = bed.wait_phase(names["deadline"], {"running", *TERMINAL_PHASES}, timeout=300)
        assert status(deadline_job)["phase"] == "running", explain(status(deadline_job))  # else: no start in its window
        collected_job = bed.job(names["collected"])
        collected_pod = bed.wait(lambda: pod_of(bed, collected_job), 60, "the collected job's pod")
        bed.kill_agent()  # nothing of armnet's watches the jobs from here on
        state = AgentOutage(bed, {"deadline": deadline_job, "collected": collected_job},
                            {"deadline": pod_of(bed, deadline_job), "collected": collected_pod}, collector)
        bed.wait(lambda: "Proceeding to collect garbage" in collector.log_tail(100_000), 120,
                 "the garbage collector to sync its caches", every=1.0)
        yield state
    finally:
        collector.stop()
        if state is not None:
            state.restart()


def test_a_deleted_robotjobs_pod_is_collected_by_the_garbage_collector_through_its_owner_reference(
    bed: AgentBed, outage: AgentOutage
) -> None:
    """With the agent down (running, it stops a deleted job's pod itself), only the owner reference acts.

    A foreground deletion: the operator's finalizer keeps a running RobotJob while its agent is
    away (until the cancel is forced); a background one would collect the pod only once the
    RobotJob is gone. In the foreground the collector deletes the dependents at once.
    """
    job, pod = outage.jobs["collected"], outage.pods["collected"]
    assert pod is not None, "the job's pod"
    owner, = pod["metadata"]["ownerReferences"]
    assert owner == {"apiVersion": API_VERSION, "kind": "RobotJob", "name": job["metadata"]["name"],
                     "uid": job["metadata"]["uid"], "controller": True, "blockOwnerDeletion": False}, owner
    bed.k8s.kubectl("delete", "rj", job["metadata"]["name"], "-n", bed.namespace, "--cascade=foreground",
                    "--wait=false")
    bed.wait(lambda: pod_of(bed, job) is None, 120, "the garbage collector to delete the pod", every=1.0)


def test_the_kubelet_ends_a_job_pod_at_its_active_deadline_with_the_agent_stopped(
    bed: AgentBed, outage: AgentOutage
) -> None:
    from armnet_launch.pod import job_start_delay_s
    from armnet_launch.pod_spec import DEADLINE_MARGIN_S, active_deadline_seconds

    job, pod = outage.jobs["deadline"], outage.pods["deadline"]
    assert pod is not None, "the job's pod"
    # Created with room to start (image pulls), lowered once the job ran to timeout + the cell's
    # grace (3 s) + the margin from the job container's own start: the agent's kill comes first while it runs.
    deadline = pod["spec"]["activeDeadlineSeconds"]
    delay = job_start_delay_s(pod)
    assert delay is not None, pod.get("status")
    assert deadline < active_deadline_seconds(OUTLIVES_TIMEOUT, 3), deadline
    assert deadline == int(delay + 0.999) + OUTLIVES_TIMEOUT + 3 + DEADLINE_MARGIN_S, (deadline, delay)

    def ended() -> dict[str, Any] | None:
        current = pod_of(bed, job)
        return current if current and (current.get("status") or {}).get("phase") == "Failed" else None

    ended_pod = bed.wait(ended, deadline + 90, "the kubelet to end the pod at its deadline", every=1.0)
    assert ended_pod["status"].get("reason") == "DeadlineExceeded", ended_pod["status"]
    job_state = {c["name"]: c["state"] for c in ended_pod["status"].get("containerStatuses") or []}["job"]
    assert "terminated" in job_state, job_state
    # Its own deadline, not the agent's kill (which lowers it to 1 s), and nobody else ended the job.
    assert ended_pod["spec"]["activeDeadlineSeconds"] == deadline, ended_pod["spec"]["activeDeadlineSeconds"]
    assert status(bed.job(job["metadata"]["name"]))["phase"] == "running"


def test_the_restarted_agent_reports_the_deadline_ended_job_as_a_timeout_and_the_deleted_job_goes(
    bed: AgentBed, outage: AgentOutage
) -> None:
    outage.restart()
    # Re-adopted from the ended pod: the job's clock (from startedAt) ran out long ago, so the agent
    # reports a timeout whose job was killed, whatever ended the pod; then it removes the pod.
    ended = outage.jobs["deadline"]
    st = status(bed.wait_phase(ended["metadata"]["name"], timeout=180))
    assert st["phase"] == "timeout", explain(st)
    assert f"job exceeded its timeout of {OUTLIVES_TIMEOUT} s" in st["result"]["error"], explain(st)
    bed.wait(lambda: pod_of(bed, ended) is None, 60, "the agent to remove the ended pod")
    # The deleted job's pod is gone: the agent fails the job, and the operator lets the RobotJob go.
    deleted = outage.jobs["collected"]["metadata"]["name"]
    bed.wait(lambda: not bed.job_exists(deleted), 120, "the deleted RobotJob to finish deleting")
