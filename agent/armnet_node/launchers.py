"""Where the node agent runs a job: a container-engine container or a Kubernetes pod (``--launcher``).

Both launchers give the runner the same things, so there is one run path
(``runner.JobRunner``): the launched job for the supervisor (``LaunchedJob``),
the job's record from the connector, and a way to find, adopt and remove the
jobs a previous agent process started (by label).

- ``ContainerLauncher``: the customer container through the Docker API; the
  connector runs in the agent's process on the cell's simulator (``LocalCell``).
- ``PodLauncher``: one pod per job on this node (``launch.pod_spec``), the
  connector as its native sidecar; the agent keeps the cell's simulator and
  hands its ptys (or a real cell's devices) to the connector container only,
  through the agent's device plugin (``deviceplugin``) or hostPath volumes;
  or, when the agent runs in a pod itself (``simulator_in_pod``: its ptys are
  its container's own), the sidecar runs a simulated cell's simulator and no
  device reaches the pod.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from armnet_connector.inputs import LocalOperatorInputs, OperatorInputs
from armnet_core.cell_completion import host_files
from armnet_launch.container import ContainerJob
from armnet_launch.plan import LABEL_JOB_UID, LABEL_MANAGED_BY, MANAGED_BY_AGENT
from armnet_launch.pod import PodExists, PodJob
from armnet_launch.pod_spec import (
    CONNECTOR_USER,
    JOB_USER,
    OBSERVER_DIR,
    PodInputs,
    PodResources,
    SecretRef,
    active_deadline_seconds,
    build_pod,
    device_path,
    running_deadline_seconds,
)
from armnet_launch.sidecar import SidecarConfig
from armnet_launch.sim_cell import LocalCell, build_connector_config
from armnet_launch.supervise import LaunchedJob
from armnet_runtime import env as env_keys
from armnet_sim.calibration import builtin_calibration, dump_calibration
from armnet_sim.presets import PRESETS, CellSimulator

from armnet_node import report
from armnet_node.deviceplugin.decide import resource_name
from armnet_node.metrics import AgentMetrics
from armnet_node.model import Cell, Job
from armnet_node.plan import LaunchPlan, container_name
from armnet_node.sidecar_inputs import SidecarInputs, agent_socket
from armnet_node.sidecar_observer import (
    DEFAULT_KUBELET_ROOT,
    SidecarObserver,
    observer_socket,
    parse_event,
)
from armnet_node.telemetry_sources import InProcessView, JobView

log = logging.getLogger(__name__)

#: Beyond the pod's own ``activeDeadlineSeconds`` (the kubelet fails a pod that has not run by then):
#: the agent's bound on that wait, should the kubelet never report.
POD_START_MARGIN_S = 60
CONNECTOR_RESTARTED = (
    "the connector sidecar restarted during the job (the kubelet restarts a sidecar that dies); it came back with "
    "the interlock tripped and the job was failed rather than resumed"
)


class JobSession(Protocol):
    """One job's launch on one launcher, from start (or adoption) to removal."""

    def start(self) -> LaunchedJob: ...

    def on_deadline(self) -> None: ...

    def on_cancel(self, why: str | None = None) -> None:
        """Open the grace window of a graceful stop (the interlock's reason names the cancel, or ``why``)."""
        ...

    def on_preempt(self, why: str) -> None:
        """Ask the connector to open the grace window at the job's next episode boundary (at once between
        rollouts), its interlock naming ``why``; never raises. Any number of calls: the first ``why`` stands."""
        ...

    def preempt_began(self) -> bool:
        """Whether the connector has opened the grace window ``on_preempt`` asked for (the boundary came)."""
        ...

    def failure(self) -> str | None:
        """An infrastructure failure that overrides the job's own result (OOM, connector restart)."""
        ...

    def record(self) -> report.ConnectorRecord: ...

    def rollout(self) -> dict[str, int] | None: ...

    def active_rollout(self) -> int | None:
        """The rollout the job is in now (its last rollout event is a begin), else None."""
        ...

    def rollout_events(self) -> Sequence[Any]:
        """The connector's latest rollout begins and ends, oldest first (``connector.cell.RolloutEvent``)."""
        ...

    def interlock_trip(self) -> str | None: ...

    def auto_reset_latest(self) -> Mapping[str, Any] | None:
        """The job's latest scripted reset as the connector reports it (``AutoResetReport.as_status()``), while the
        job runs; None when it made none, or when the connector is out of reach (a pod: its record has it)."""
        ...

    def job_view(self) -> JobView | None:
        """What the job's connector knows, for telemetry (in this process, or a pod sidecar's observer socket)."""
        ...

    def operator_inputs(self) -> OperatorInputs | SidecarInputs:
        """Where the cell operator's inputs go (the inputs bridge): the connector in this process, or a pod's sidecar."""
        ...

    def remove(self) -> None: ...


@dataclass(frozen=True)
class SessionRequest:
    job: Job
    cell: Cell
    plan: LaunchPlan
    sim: CellSimulator | None
    #: The launcher's handle of a job a previous agent started (re-adoption), else None.
    adopted: Any
    tripped: str | None
    inputs: LocalOperatorInputs
    on_grace_expired: Callable[[], None]
    secret_refs: tuple[SecretRef, ...] = ()
    #: Whether the job was asked to stop (cancel, deletion, device loss): a launch still starting ends.
    stop_requested: Callable[[], bool] = lambda: False


class JobLauncher(Protocol):
    kind: str
    secrets_by_ref: bool
    #: The uid the connector runs as when it is not this process (a pod's sidecar), else None.
    connector_uid: int | None
    #: A simulated cell's cameras, as the job's connector opens them, draw the arm (they reach the
    #: simulator's joint state): a completion monitor can see the task.
    simulated_cameras_draw_the_arm: bool

    def running(self) -> dict[str, Any]:
        """Job uid -> a row of every job this agent's launcher started and did not remove."""
        ...

    def row_labels(self, row: Any) -> Mapping[str, str]: ...

    def handle(self, row: Any) -> Any:
        """The adoptable handle of a row, or None if it is gone since the list."""
        ...

    def remove(self, row: Any) -> None: ...

    def session(self, request: SessionRequest) -> Any:
        """A context manager yielding the job's :class:`JobSession`."""
        ...


# -- the container engine ----------------------------------------------------------------


class ContainerLauncher:
    kind = "container"
    #: Secrets reach the container as env values (the Docker API has no secret references).
    secrets_by_ref = False
    #: The connector runs in this process, beside the simulator.
    connector_uid: int | None = None
    simulated_cameras_draw_the_arm = True

    def __init__(self, engine: Any, metrics: AgentMetrics) -> None:
        self.engine = engine
        self.metrics = metrics

    def running(self) -> dict[str, Any]:
        rows = self.engine.api.containers(all=True, filters={"label": f"{LABEL_MANAGED_BY}={MANAGED_BY_AGENT}"})
        return {(row.get("Labels") or {}).get(LABEL_JOB_UID, ""): row for row in rows}

    def row_labels(self, row: Any) -> Mapping[str, str]:
        return dict(row.get("Labels") or {})

    def handle(self, row: Any) -> Any:
        try:
            return self.engine.containers.get(row["Id"])
        except Exception:  # noqa: BLE001 - gone between the list and now
            return None

    def remove(self, row: Any) -> None:
        try:
            self.engine.api.remove_container(row["Id"], force=True)
        except Exception:  # noqa: BLE001 - already gone
            log.debug("removing a container failed", exc_info=True)

    @contextmanager
    def session(self, request: SessionRequest) -> Iterator[ContainerSession]:
        plan = request.plan
        local_cell = LocalCell(
            plan.cell_spec, plan.layout.socket_dir.parent, layout=plan.layout, sim=request.sim,
            inputs=request.inputs, on_grace_expired=request.on_grace_expired, tripped=request.tripped,
            timeout_s=plan.timeout_seconds,
        )
        with local_cell:
            yield ContainerSession(self, request, local_cell)


class ContainerSession:
    def __init__(self, launcher: ContainerLauncher, request: SessionRequest, local_cell: LocalCell) -> None:
        self.launcher = launcher
        self.request = request
        self.local_cell = local_cell
        self.job: ContainerJob | None = None

    def start(self) -> LaunchedJob:
        adopted = self.request.adopted
        if adopted is not None:
            if adopted.status == "created":
                adopted.start()
            self.job = ContainerJob.adopt(self.launcher.engine, adopted)
        else:
            self.job = ContainerJob.launch(self.launcher.engine, self.request.plan.container)
        via = "file" if self.job.log_file is not None else "engine_api"
        self.launcher.metrics.job_log_reads.labels(via=via).inc()
        return self.job

    def on_deadline(self) -> None:
        self.local_cell.pass_deadline()

    def on_cancel(self, why: str | None = None) -> None:
        self.local_cell.cancel(why)

    def on_preempt(self, why: str) -> None:
        connector = self.local_cell.connector
        if connector is not None:
            connector.cell.stop_at_episode_end(why)

    def preempt_began(self) -> bool:
        """The connector's interlock holds: the preemption's grace window opened (or another trip refuses
        motion already, and the agent's stop may begin as well)."""
        return self.interlock_trip() is not None

    def failure(self) -> str | None:
        if self.job is not None and self.job.oom_killed:
            return "the container was killed for exceeding its memory limit (OOM)"
        return None

    def job_view(self) -> JobView | None:
        connector = self.local_cell.connector
        return InProcessView(connector.cell) if connector is not None else None

    def operator_inputs(self) -> OperatorInputs | SidecarInputs:
        return self.request.inputs

    def interlock_trip(self) -> str | None:
        connector = self.local_cell.connector
        trip = connector.interlock.trip_info if connector is not None else None
        return trip.message if trip is not None else None

    def auto_reset_latest(self) -> Mapping[str, Any] | None:
        connector = self.local_cell.connector
        resets = list(connector.cell.auto_resets) if connector is not None else []
        return resets[-1].as_status() if resets else None

    def rollout(self) -> dict[str, int] | None:
        connector = self.local_cell.connector
        if connector is None:
            return None
        for event in reversed(list(connector.cell.rollouts)):
            if event.kind == "begin" and event.index is not None:
                return {"index": event.index, "total": event.total or 0}
        return None

    def active_rollout(self) -> int | None:
        connector = self.local_cell.connector
        if connector is None:
            return None
        events = list(connector.cell.rollouts)
        return events[-1].index if events and events[-1].kind == "begin" else None

    def rollout_events(self) -> Sequence[Any]:
        connector = self.local_cell.connector
        return list(connector.cell.rollouts) if connector is not None else []

    def record(self) -> report.ConnectorRecord:
        """The connector's account of the job, its safety report taken once it has let go of the arm.

        Why the report after the stop: the connector's final release (torque off, read
        back from the servos) belongs in the result's ``safety.torqueOffConfirmed``;
        taken before, the report would only hold what the job's own closes did. The
        interlock is read before: stopping trips it (teardown, not the job's doing).
        """
        connector = self.local_cell.connector
        if connector is None:
            return report.ConnectorRecord()
        trip = connector.interlock.trip_info
        rollout = self.rollout()
        violations = connector.counters.safety_violations
        self.local_cell.stop_connector()
        return report.ConnectorRecord(
            trip_reason=trip.reason.value if trip is not None else None,
            trip_message=trip.message if trip is not None else None,
            safety_violations=violations,
            rollout_index=rollout["index"] if rollout else None,
            rollout_total=rollout["total"] if rollout else None,
            safety=connector.safety_report().as_status(),
            cell_record=connector.cell_record_counts(),
        )

    def remove(self) -> None:
        if self.job is not None:
            self.job.remove()


# -- Kubernetes pods -----------------------------------------------------------------------


@dataclass(frozen=True)
class PodSettings:
    node_name: str
    connector_image: str
    connector_command: tuple[str, ...] = ("python3", "-m", "armnet_launch.sidecar")
    image_pull_policy: str = "IfNotPresent"
    resources: PodResources = PodResources()
    job_read_only_root: bool = True
    job_user: int = JOB_USER
    #: The connector sidecar's uid (``pod_spec.CONNECTOR_USER``); 0 only for development stand-in images.
    connector_user: int = CONNECTOR_USER
    dev_mounts: tuple[str, ...] = ()
    dev_env: Mapping[str, str] = field(default_factory=dict)
    #: The connector requests the cell's extended resource (the agent's device plugin gives the
    #: devices); False: hostPath CharDevice volumes, for kubelets without device plugins.
    device_plugin: bool = False
    #: A simulated cell's simulator runs in the job pod's sidecar, not in the agent (an agent in a pod).
    simulator_in_pod: bool = False

    def devices_through_plugin(self, *, simulated: bool) -> bool:
        """Whether a job pod on such a cell gets the cell's devices through the agent's device plugin.

        Not when its simulator runs in the sidecar: the agent's ptys are then its own
        container's, and a bind mount of that path on the host is another terminal or none.
        """
        return self.device_plugin and not (simulated and self.simulator_in_pod)
    #: The kubelet's ``--root-dir`` as this agent sees it: pods' observer sockets are found under it.
    kubelet_root: Path = DEFAULT_KUBELET_ROOT


class PodLauncher:
    kind = "pod"
    #: Secrets reach the pod as ``secretKeyRef`` env vars: the agent never holds the values.
    secrets_by_ref = True

    def __init__(self, core: Any, settings: PodSettings, metrics: AgentMetrics, namespaces: tuple[str, ...] = ()) -> None:
        self.core = core
        self.settings = settings
        self.metrics = metrics
        self.namespaces = namespaces
        self.connector_uid: int | None = settings.connector_user
        # The sidecar's cameras draw the arm only when the simulator runs in the pod beside them.
        self.simulated_cameras_draw_the_arm = settings.simulator_in_pod

    def running(self) -> dict[str, Any]:
        """This node's job pods, by label (re-adoption reads the pod, never the agent's memory)."""
        selector = f"{LABEL_MANAGED_BY}={MANAGED_BY_AGENT}"
        node = f"spec.nodeName={self.settings.node_name}"
        if self.namespaces:
            items = [p for ns in self.namespaces for p in self.core.list_namespaced_pod(
                ns, label_selector=selector, field_selector=node).items]
        else:
            items = self.core.list_pod_for_all_namespaces(label_selector=selector, field_selector=node).items
        rows = [self.core.api_client.sanitize_for_serialization(pod) for pod in items]
        return {(row["metadata"].get("labels") or {}).get(LABEL_JOB_UID, ""): row for row in rows}

    def row_labels(self, row: Any) -> Mapping[str, str]:
        return dict(row["metadata"].get("labels") or {})

    def handle(self, row: Any) -> Any:
        return row

    def remove(self, row: Any) -> None:
        meta = row["metadata"]
        PodJob(self.core, meta["namespace"], meta["name"], follow=False).delete(grace_seconds=0)

    @contextmanager
    def session(self, request: SessionRequest) -> Iterator[PodSession]:
        session = PodSession(self, request)
        try:
            yield session
        finally:
            session.close_observer()  # also when the run failed before removing the pod

    def manifest(self, request: SessionRequest) -> dict[str, Any]:
        """The job's pod (pure given the request: ``launch.pod_spec`` decides its shape)."""
        s = self.settings
        plan, job, cell = request.plan, request.job, request.cell
        layout = plan.layout
        ports = {arm.name: device_path(arm.name) for arm in layout.arms}
        config = build_connector_config(plan.cell_spec, layout, ports)
        # In a pod the connector runs the job's clock (the agent cannot call into it).
        # Its clock starts with the job (the agent's job_started notice, or the job's first connection),
        # not with the sidecar, which runs before the job's image is pulled and its container started.
        config = config.model_copy(update={"timeout_seconds": float(job.timeout_seconds), "clock_starts_with_job": True})
        shipped = {preset.name: preset.calibration for preset in PRESETS[plan.cell_spec.preset]}
        calibration = {
            str(arm.calibration_file): json.loads(dump_calibration(builtin_calibration(shipped[arm.name])))
            for arm in layout.arms
        }
        in_pod = request.sim is not None and s.simulator_in_pod
        simulator = {"preset": plan.cell_spec.preset, "latency_ms": plan.cell_spec.latency_ms} if in_pod else None
        record_dir = str(layout.record_dir) if layout.record_dir is not None else None
        sidecar = SidecarConfig(config.model_dump(mode="json"), str(layout.socket_dir), calibration, simulator,
                                observer_dir=OBSERVER_DIR, record_dir=record_dir)
        devices = dict(request.sim.ports()) if request.sim is not None and not in_pod else {}
        env = dict(plan.container.env)
        if request.secret_refs:
            env[env_keys.SECRETS] = json.dumps(sorted(ref.env for ref in request.secret_refs))
        inputs = PodInputs(
            name=container_name(job.uid),
            namespace=job.namespace,
            node_name=s.node_name,
            job_name=job.name,
            job_uid=job.uid,
            labels=plan.container.labels,
            job_image=job.image,
            job_env=env,
            connector_image=s.connector_image,
            connector_command=s.connector_command,
            sidecar=sidecar.as_data(),
            socket_dir=str(layout.socket_dir),
            calibration_dir=str(layout.calibration_dir),
            cache_dir=str(layout.cache_dir),
            volume_dir=str(layout.volume_dir),
            output_dir=str(layout.output_dir),
            timeout_seconds=job.timeout_seconds,
            grace_seconds=cell.grace_seconds,
            job_command=plan.container.command,
            secrets=request.secret_refs,
            devices={} if s.device_plugin else {arm: devices[arm] for arm in ports if arm in devices},
            device_resource=(resource_name(cell.name)
                             if s.devices_through_plugin(simulated=request.sim is not None) else None),
            resources=s.resources,
            dev_mounts=s.dev_mounts,
            connector_env=dict(s.dev_env),
            image_pull_policy=s.image_pull_policy,
            job_read_only_root=s.job_read_only_root,
            job_user=s.job_user,
            connector_user=s.connector_user,
            observer_dir=OBSERVER_DIR,
            record_dir=record_dir,
            host_files=host_files(cell.completion),
        )
        return build_pod(inputs)


class PodSession:
    def __init__(self, launcher: PodLauncher, request: SessionRequest) -> None:
        self.launcher = launcher
        self.request = request
        self.job: PodJob | None = None
        #: The sidecar connector's observer socket (telemetry, rollout events), once the pod exists.
        self.observer: SidecarObserver | None = None
        self._record: report.ConnectorRecord | None = None
        #: The sidecar connector's ``agent.sock``: the operator's inputs, the cancel and the preemption.
        self.inputs = SidecarInputs(lambda: agent_socket(self._observer_path()), launcher.metrics,
                                    active_rollout=self.active_rollout)
        #: The preemption's reason once asked (``on_preempt``), and whether the sidecar said its window is open.
        self._preempt_why: str | None = None
        self._preempt_open = False

    def start(self) -> LaunchedJob:
        core, metrics = self.launcher.core, self.launcher.metrics
        request = self.request
        job: PodJob | None = None
        timeout, grace = request.job.timeout_seconds, request.cell.grace_seconds

        def running_deadline(started_after_s: float) -> int:
            return running_deadline_seconds(timeout, grace, started_after_s)

        if request.adopted is None:
            self._own_host_dirs()
            try:
                job = PodJob.launch(core, self.launcher.manifest(request), on_started=metrics.pod_start_latency.observe,
                                    running_deadline=running_deadline)
            except PodExists:
                pass  # this job's pod from an agent that died before it wrote running: adopt it
        if job is None:
            job = PodJob.adopt(core, request.job.namespace, container_name(request.job.uid),
                               running_deadline=running_deadline)
        self.job = job
        self.observer = SidecarObserver(self._observer_path, metrics)
        self.inputs.watch(self._job_running)  # reset waits, announced to the cell's operator
        self._wait_for_job_container(job)
        return job

    def _wait_for_job_container(self, job: PodJob) -> None:
        """"running" means the job's code runs, and its timeout counts from there: wait for its container.

        A pod starts slowly when the node is busy or the job's image is pulled (the sidecar is
        ready first); the job's clock must not run meanwhile (it did, after a fixed 120 s: a
        loaded test run timed out a job whose code had run for 4 s). The kubelet's own start
        allowance (``activeDeadlineSeconds``) bounds the wait; a stop request ends it early.
        """
        request = self.request
        bound_s = active_deadline_seconds(request.job.timeout_seconds, request.cell.grace_seconds) + POD_START_MARGIN_S
        ended = job.wait_for_job_container(request.stop_requested, bound_s)
        if ended is not None:
            log.warning("job %s: its pod was ended before its container started: %s", request.job.key, ended)
        elif job.wait(0) is None and not self.inputs.job_started():
            # The job's first connection starts the connector's clock then; the agent's own clock runs.
            log.warning("job %s: the job_started notice did not reach its connector sidecar", request.job.key)

    def _own_host_dirs(self) -> None:
        """The cache, volume and output are host directories: the job's non-root user must be able to write them;
        the cell's record is the connector's (its uid), never the job's."""
        layout = self.request.plan.layout
        owners = [(directory, self.launcher.settings.job_user)
                  for directory in (layout.cache_dir, layout.volume_dir, layout.output_dir)]
        if layout.record_dir is not None:
            owners.append((layout.record_dir, self.launcher.settings.connector_user))
        for directory, uid in owners:
            directory.mkdir(parents=True, exist_ok=True)
            try:
                os.chown(directory, uid, uid)
            except PermissionError:
                log.warning("cannot hand %s to uid %d (the agent is not root): it cannot write there", directory, uid)

    def on_deadline(self) -> None:
        """Nothing to call: the sidecar runs the job's deadline itself; the supervisor kills after grace."""

    def on_cancel(self, why: str | None = None) -> None:
        """Open the sidecar connector's grace window (``agent.sock``), its interlock naming ``why`` (a lost
        device; default: cancelled); the supervisor still kills after grace."""
        if not self.inputs.cancel(why):
            log.warning("job %s: the cancel did not reach its connector sidecar; the job is killed when the grace "
                        "window ends without having been told it is shutting down", self.request.job.key)

    def on_preempt(self, why: str) -> None:
        """The ``preempt`` op on the sidecar's ``agent.sock``; one that does not arrive is asked again by
        ``preempt_began`` (the op is idempotent)."""
        self._preempt_why = why
        now = self.inputs.preempt(why)
        if now is None:
            log.warning("job %s: the preemption did not reach its connector sidecar yet; it is asked again until "
                        "it does, or until the agent opens the grace window itself", self.request.job.key)
        self._preempt_open = now is True

    def preempt_began(self) -> bool:
        """Asks the sidecar (its interlock is in the pod, out of ``interlock_trip``'s reach) until it says the
        window is open; from then on, without asking."""
        why = self._preempt_why
        if why is None:
            return False
        if not self._preempt_open:
            self._preempt_open = self.inputs.preempt_window_open(why)
        return self._preempt_open

    def failure(self) -> str | None:
        job = self.job
        if job is None:
            return None
        if job.connector_restarts > 0:
            self.launcher.metrics.connector_restarts.inc()
            record = self.record()
            if record.trip_message:
                return f"{CONNECTOR_RESTARTED} (connector record: {record.trip_reason}: {record.trip_message})"
            return CONNECTOR_RESTARTED
        if job.failure is not None:
            self.launcher.metrics.pod_failures.labels(reason=_reason_label(job.failure)).inc()
            return f"the job's pod ended without running the job: {job.failure}"
        if job.oom_killed:
            return "the job container was killed for exceeding its memory limit (OOM)"
        return None

    def job_view(self) -> JobView | None:
        return self.observer if self._job_running() else None

    def operator_inputs(self) -> OperatorInputs | SidecarInputs:
        return self.inputs

    def _job_running(self) -> bool:
        """The job's container runs: the sidecar serves (it is ready first) and has not been stopped yet.

        Outside that window the observer socket is not asked (it is not there yet, or gone after the job's
        exit), so a connection failure counted by the observer means something an operator should see.
        """
        job = self.job
        return job is not None and job.wait_started(0) and job.wait(0) is None

    def interlock_trip(self) -> str | None:
        return None  # the connector is in the pod; its trips reach the status through its record

    def auto_reset_latest(self) -> Mapping[str, Any] | None:
        return None  # likewise: the record's safety report carries the latest (``autoResets``)

    def rollout(self) -> dict[str, int] | None:
        """The last rollout begun, from the events the recorder last read (no request of its own)."""
        observer = self.observer
        for event in reversed(observer.take_events(()) if observer is not None else []):
            if event.kind == "begin" and event.index is not None:
                return {"index": event.index, "total": event.total or 0}
        return None

    def active_rollout(self) -> int | None:
        """Asked when a verdict arrives: the sidecar's events now (its last is a begin), else None."""
        events = list(self.rollout_events())
        return events[-1].index if events and events[-1].kind == "begin" else None

    def rollout_events(self) -> Sequence[Any]:
        """The sidecar's events through its observer socket; once it has stopped, with its record's last ones."""
        observer = self.observer
        if observer is None:
            return []
        if self._record is not None or not self._job_running():
            # Not yet started, or the job has exited (the kubelet stops the sidecar next): its record
            # carries the last events.
            return observer.take_events(())
        return observer.rollout_events()

    def record(self) -> report.ConnectorRecord:
        if self._record is None:
            data = self.job.connector_record() if self.job is not None else None
            self._record = _connector_record(data)
            if self.observer is not None and data:
                self.observer.take_events(record_events(data))
        return self._record

    def _observer_path(self) -> Path | None:
        pod = self.job.last_pod if self.job is not None else {}
        uid = (pod.get("metadata") or {}).get("uid")
        return observer_socket(self.launcher.settings.kubelet_root, uid) if isinstance(uid, str) else None

    def close_observer(self) -> None:
        """Stop the sidecar channels: the reset-wait poll of ``agent.sock`` and the observer's connection."""
        self.inputs.close()
        if self.observer is not None:
            self.observer.close()

    def remove(self) -> None:
        self.close_observer()
        if self.job is not None:
            self.job.remove()


def record_events(data: Mapping[str, Any]) -> list[Any]:
    """The rollout events in a sidecar's record (its last ones: the observer may have missed the final end)."""
    events = []
    for item in data.get("rollouts") or []:
        try:
            events.append(parse_event(item))
        except ValueError:
            log.warning("a malformed rollout event in the connector sidecar's record was skipped")
    return events


def _reason_label(failure: str) -> str:
    """A bounded label value for the failure counter."""
    for known in ("ErrImageNeverPull", "ErrImagePull", "ImagePullBackOff", "DeadlineExceeded", "deleted",
                  "CreateContainerConfigError", "CreateContainerError", "RunContainerError"):
        if known in failure:
            return known
    return "other"


def _connector_record(data: Mapping[str, Any] | None) -> report.ConnectorRecord:
    if not data:
        return report.ConnectorRecord()
    return report.ConnectorRecord(
        trip_reason=data.get("trip_reason"),
        trip_message=data.get("trip_message"),
        safety_violations=int(data.get("safety_violations") or 0),
        rollout_index=data.get("rollout_index"),
        rollout_total=data.get("rollout_total"),
        safety=dict(data.get("safety") or {}),
        cell_record=report.cell_record_counts(data.get("cell_record")),
    )

