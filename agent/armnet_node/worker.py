"""One Cell of this host: its simulator (simulated cells), heartbeat, health, and the job it runs.

The agent's pass hands each worker the latest Cell and the jobs bound to it;
the worker decides (``observe``) whether to launch, adopt, stop or fail a job
and keeps at most one runner at a time (the operator's binding says which).
Its heartbeat thread renews ``status.lastHeartbeatTime`` and the health
conditions every ``heartbeat_period`` seconds, and at once when the cell's
device watch (``node.device_watch``) changes its verdict; a lost device also
stops the running job (it ends ``failed``, "device lost"). A running job the
operator preempted (``status.preemption``) is handed to its runner, which
stops it at its next episode boundary.

A simulated cell's arm ports are reached through symlinks the worker makes to
the simulator's ptys, ``<state-dir>/cells/<cell>/dev/<arm>`` (as udev makes
``/dev/serial/by-id/...`` for a USB adapter): these are the cell's device
paths, so removing one is what the device watch sees of a pulled cable (fault
injection; put the link back to plug it in again). The running job's bus keeps
working on the pty: only the verdict sees the removal, and the worker then
stops the job.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from armnet_core.api import ACTIVE_PHASES, SIM_UNPLUG_ANNOTATION, TERMINAL_PHASES, JobPhase
from armnet_core.cell_completion import host_files
from armnet_core.conditions import remove_condition
from armnet_core.times import status_time
from armnet_sim.calibration import builtin_calibration, write_calibration
from armnet_sim.presets import PRESETS, CellSimulator
from armnet_sim.process import SimulatedCellProcess

from armnet_node import device_health, health, report
from armnet_node.bus_turns import BusTurns
from armnet_node.completion_configmap import resolved_cell
from armnet_node.completion_model import CompletionFilesCheck
from armnet_node.device_watch import DeviceWatch
from armnet_node.deviceplugin.decide import DevicePath, cell_device_paths
from armnet_node.kube import Conflict, Gone, KubeError
from armnet_node.model import (
    Cell,
    Job,
    should_launch,
)
from armnet_node.plan import LaunchError, cell_spec_for
from armnet_node.probes import probe_arm
from armnet_node.publish import job_output, streams_probe, telemetry_notifier
from armnet_node.runner import JobRunner, RunnerDeps
from armnet_node.telemetry import CellTelemetry, TelemetrySettings, TelemetrySource
from armnet_node.telemetry_sources import (
    EMBODIMENT_MOTOR_MODEL,
    ArmPort,
    IdleArms,
    IdleCameras,
    IdleSource,
    JobSource,
)

log = logging.getLogger(__name__)

VANISHED = "the job's container vanished while the node agent was not watching it (removed, or the host restarted)"


@dataclass(frozen=True)
class WorkerSettings:
    heartbeat_period: float = 5.0
    telemetry: TelemetrySettings = field(default_factory=TelemetrySettings)


class CellWorker:
    def __init__(self, cell: Cell, deps: RunnerDeps, settings: WorkerSettings) -> None:
        self.cell = cell
        self.deps = deps
        self.settings = settings
        self.sim: CellSimulator | None = None
        self.runner: JobRunner | None = None
        self._finished_uids: set[str] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        #: Wakes the heartbeat before its period (the device verdict changed, or the worker stops).
        self._wake = threading.Event()
        self._sim_links: dict[str, Path] = {}
        self.devices = DeviceWatch(cell.name, self.device_paths, self._devices_changed, deps.metrics)
        #: The devices' HardwareReady problem the heartbeat was last woken for (``_devices_changed``).
        self._hardware_problem: tuple[str, str] | None = None
        self._last_probe: health.CellProbe | None = None
        self._bus = BusTurns()
        self._unplugged: frozenset[str] = frozenset()
        self._calibration_files: dict[str, Path] = {}
        self._idle_cameras = IdleCameras()
        self._idle_arms = IdleArms()
        self._telemetry: CellTelemetry | None = None
        #: The latest scripted reset a job on this cell reported (``AutoResetWorking``), across jobs.
        self._auto_reset: Mapping[str, Any] | None = None
        # The uid the connector reads the cell's completion files as: a pod's sidecar's, or this process's.
        reader_uid = getattr(deps.launcher, "connector_uid", None)
        self._completion_files = CompletionFilesCheck(deps.paths.completion_dirs, reader_uid,
                                                      (str(deps.paths.completion_models_of(cell.name)),))
        self._cameras_draw_the_arm = bool(getattr(deps.launcher, "simulated_cameras_draw_the_arm", True))
        self._thread = threading.Thread(target=self._heartbeat_loop, name=f"armnet-cell-{cell.name}", daemon=True)

    @property
    def name(self) -> str:
        return self.cell.name

    @property
    def telemetry(self) -> CellTelemetry | None:
        """The cell's telemetry thread (None without NATS or with telemetry off)."""
        return self._telemetry

    def start(self) -> CellWorker:
        """Start the cell's simulator, device watch and heartbeat; on a failure, stop what started, then raise.

        The agent's next pass makes a new worker: nothing of this one (a simulator, its links) is left behind.
        """
        try:
            if self.cell.simulated:
                self._start_sim()
            self.devices.start()
            self._thread.start()
            notifier = telemetry_notifier(self.deps.link)
            if notifier is not None and self.settings.telemetry.enabled:
                self._telemetry = CellTelemetry(
                    self.cell.name, self.telemetry_source, notifier, self.deps.metrics, self.settings.telemetry,
                    on_exit=self._close_telemetry_devices,
                ).start()
        except BaseException:
            self._stop.set()
            self._wake.set()
            self.devices.stop()
            if self._thread.is_alive():
                self._thread.join(5)
            self._release_sim()
            raise
        return self

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        self.devices.stop()
        if self._telemetry is not None:
            self._telemetry.stop()  # the thread closes its cameras and port handles as it leaves
        runner = self.runner
        if runner is not None:
            runner.stop()
        self._thread.join(5)
        self._release_sim()

    def _release_sim(self) -> None:
        """Stop the simulator and remove the links to its ptys (no-op for a real cell)."""
        if self.sim is not None:
            self.sim.stop()
        for link in self._sim_links.values():
            with contextlib.suppress(OSError):
                link.unlink()
        self._sim_links.clear()

    def _start_sim(self) -> None:
        try:
            spec = cell_spec_for(self.cell)
        except LaunchError as exc:
            log.error("%s", exc)
            return
        calibrations = {}
        directory = self.deps.paths.state_dir / "cells" / self.cell.name / "calibration"
        for preset in PRESETS[spec.preset]:
            calibration = builtin_calibration(preset.calibration)
            calibrations[preset.name] = calibration
            robot_id = spec.robot_id if spec.preset == "so101" else f"{spec.robot_id}_{preset.name}"
            self._calibration_files[preset.name] = write_calibration(directory / f"{robot_id}.json", calibration)
        # In a child process, not in the agent's: the simulated servos' serving threads would
        # otherwise share the agent's GIL with its watches, log streams and telemetry, and a
        # GIL holder the host preempts delays every reply of every cell on the node (replies
        # missed LeRobot's 50 ms reply window with four job pods starting beside a loop).
        self.sim = SimulatedCellProcess(spec.preset, calibrations=calibrations).start()
        self._link_sim_ports(self.sim.ports())
        log.info("cell %s: simulator started (%s)", self.cell.name, self.sim.ports())

    def _link_sim_ports(self, ports: dict[str, str]) -> None:
        """``<state-dir>/cells/<cell>/dev/<arm>`` -> the arm's pty: the simulated cell's device paths."""
        directory = self.deps.paths.state_dir / "cells" / self.cell.name / "dev"
        directory.mkdir(parents=True, exist_ok=True)
        for arm, pty in ports.items():
            link = directory / arm
            with contextlib.suppress(FileNotFoundError):
                link.unlink()  # a previous agent's link to a pty that is no longer ours
            os.symlink(pty, link)
            self._sim_links[arm] = link

    # -- the pass ------------------------------------------------------------------

    def update(self, cell: Cell) -> None:
        self.cell = cell
        self._apply_sim_faults()

    def observe(self, jobs: list[Job], containers: dict[str, dict[str, Any]]) -> None:
        """Launch, adopt, stop or fail the jobs bound to this cell (idempotent)."""
        with self._lock:
            runner = self.runner
            if runner is not None and runner.done:
                self._note_auto_reset(runner)
                self._finished_uids.add(runner.uid)
                self.runner = runner = None
            mine = {job.uid: job for job in jobs if job.cell_name == self.cell.name}
            if runner is not None:
                job = mine.get(runner.uid)
                if not runner.reported and (job is None or job.stopping or job.phase in TERMINAL_PHASES):
                    runner.stop()
                elif not runner.reported and job is not None and job.preemption is not None:
                    runner.preempt(job.preemption)  # once only: later passes change nothing
                self._stop_if_device_lost(runner)
                return
            for job in sorted(mine.values(), key=lambda j: j.key):
                row = containers.get(job.uid)
                if job.phase in TERMINAL_PHASES or job.uid in self._finished_uids:
                    if row is not None and job.phase in TERMINAL_PHASES:
                        self._remove(row)  # reported already; the agent died before removing it
                    continue
                if job.phase not in ACTIVE_PHASES or self.cell.current_job != job.key:
                    continue
                if row is not None:
                    container = self._container(row)
                    if container is not None:
                        self._begin(job, container)
                        return
                    continue  # removed since the list: the next pass sees it gone
                if job.phase == JobPhase.RUNNING:
                    self._vanished(job)
                    continue
                if should_launch(job, self.cell):
                    models = self.deps.completion_models
                    if models is not None and models.pending(self.cell.name):
                        continue  # the model's ConfigMap could not be read just now: the next pass asks again
                    self._begin(job, None)
                    return

    def _container(self, row: Any) -> Any:
        return self.deps.launcher.handle(row)

    def _remove(self, row: Any) -> None:
        self.deps.launcher.remove(row)

    def _begin(self, job: Job, container: Any) -> None:
        verb = "adopting" if container is not None else "launching"
        log.info("cell %s: %s job %s", self.cell.name, verb, job.key)
        with self._bus.launching():  # a probe under way ends before the job's connector opens the port
            self._idle_arms.close()  # the agent's own port handles: the job's connector opens the port
            # The job's connector opens the cameras it is asked for; a hung camera read delays this at most 2 s.
            self._idle_cameras.close(wait_s=2.0)
            # A launch onto a lost device fails before anything starts; an adopted job is stopped, failed.
            refuse = device_health.launch_refusal(self.devices.state) if container is None else None
            self.runner = JobRunner(job, self.cell, self.sim, self.deps, container=container,
                                    device_problems=lambda: self.devices.state.problems).start(refuse=refuse)
            if refuse is None:
                self._stop_if_device_lost(self.runner)
                if job.preemption is not None:  # an adopted run the operator preempted before the agent restarted
                    self.runner.preempt(job.preemption)

    # -- the cell's devices ----------------------------------------------------------

    def _devices_changed(self, state: device_health.DeviceState) -> None:
        """On the watch thread: a lost device stops the job; a new HardwareReady is written now.

        Only a change of the condition wakes the heartbeat: a device blinking within the
        debounce changes the problem list at every read, not the Cell's status.
        """
        problem = device_health.hardware_problem(state)
        if problem != self._hardware_problem:
            self._hardware_problem = problem
            self._wake.set()
        runner = self.runner
        if runner is not None:
            self._stop_if_device_lost(runner)

    def _stop_if_device_lost(self, runner: JobRunner) -> None:
        message = device_health.stop_message(self.devices.state)
        if message is not None and not runner.done and not runner.reported:
            runner.stop_device_lost(message)

    def _vanished(self, job: Job) -> None:
        log.warning("job %s: %s", job.key, VANISHED)
        body = report.failed_before_start(job.resource_version, VANISHED, datetime.now(UTC))
        try:
            self.deps.kube.patch_job_status(job.namespace, job.name, body)
            self.deps.metrics.jobs_finished.labels(outcome="failed").inc()
            job_output(self.deps.link, job.namespace, job.uid).status(JobPhase.FAILED, report.end_detail(body))
        except KubeError as exc:
            log.info("job %s: vanished-container status not written (%s); next pass decides again", job.key, exc)

    # -- heartbeat and health --------------------------------------------------------

    def _heartbeat_loop(self) -> None:
        last_ok = time.monotonic()
        while not self._stop.is_set():
            try:
                self._heartbeat()
                last_ok = time.monotonic()
            except Exception:  # noqa: BLE001 - a failed heartbeat is retried next period
                log.warning("cell %s: heartbeat failed", self.cell.name, exc_info=True)
            self.deps.metrics.heartbeat_age.labels(cell=self.cell.name).set(time.monotonic() - last_ok)
            self._wake.wait(self.settings.heartbeat_period)
            self._wake.clear()

    def probe(self) -> health.CellProbe:
        """The cell's health facts: read from the hardware when idle, else the last idle probe's.

        The devices' presence is the device watch's verdict, job or not. While a device is
        missing the bus is not read (a port that is not there answers nothing worth keeping):
        the last idle probe's facts stand, as while a job holds the bus.
        """
        devices = self.devices.state
        lost = device_health.hardware_problem(devices)
        runner = self.runner
        trip = runner.interlock_trip() if runner is not None else None
        if devices.problems:
            kept = self._last_probe or health.CellProbe(arms={})
            return health.CellProbe(arms=kept.arms, cameras=kept.cameras, interlock_trip=trip,
                                    bus_held_by_job=self._job_holds_bus(), devices_lost=lost)
        # Every device present: the bus is read, though a lost verdict may still hold (its way back).
        fresh = self._bus.probe(self._read_hardware, bus_held=self._bus_held_with_facts)
        if fresh is not None:
            self._last_probe = fresh
            return replace(fresh, devices_lost=lost)
        last = self._last_probe
        assert last is not None  # no fresh probe only when a job holds the bus and an idle probe exists
        return health.CellProbe(
            arms=last.arms, cameras=last.cameras, interlock_trip=trip, bus_held_by_job=True, devices_lost=lost,
        )

    def _bus_held_with_facts(self) -> bool:
        runner = self.runner
        return runner is not None and not runner.done and self._last_probe is not None

    def _arm_ports(self) -> dict[str, ArmPort]:
        """arm -> (serial port, calibration file, motor model): the simulator's ptys, else the Cell's arms."""
        model = EMBODIMENT_MOTOR_MODEL.get(self.cell.embodiment)
        if self.sim is not None:
            return {name: ArmPort(port, self._calibration_files.get(name), model)
                    for name, port in self.sim.ports().items()}
        ports: dict[str, ArmPort] = {}
        for name, arm in self.cell.arms.items():
            calibration = (
                Path(arm.calibration_dir) / f"{arm.robot_id}.json" if arm.calibration_dir and arm.robot_id else None
            )
            ports[name] = ArmPort(arm.port or f"<no port configured for arm {name}>", calibration, model)
        return ports

    def device_paths(self) -> tuple[DevicePath, ...]:
        """The cell's devices for its device plugin: the simulator's ptys, else the Cell's ports and cameras."""
        if self.sim is not None:
            ports = self.sim.ports()
            return cell_device_paths({arm: str(self._sim_links.get(arm, pty)) for arm, pty in ports.items()})
        cameras = tuple(c.index_or_path for c in self.cell.cameras if c.index_or_path is not None)
        return cell_device_paths({name: arm.port for name, arm in self.cell.arms.items()},
                                 () if self.cell.simulated else cameras)

    def _read_hardware(self) -> health.CellProbe:
        arms = {name: probe_arm(arm.port, arm.calibration) for name, arm in self._arm_ports().items()}
        # Simulated cameras draw the simulator; a real camera probe needs the device (not probed yet).
        cameras: dict[str, str | None] = {camera.name: None for camera in self.cell.cameras}
        return health.CellProbe(arms=arms, cameras=cameras)

    # -- telemetry for the cell operator's page ------------------------------------------

    def telemetry_source(self) -> TelemetrySource | None:
        """Who reads the cell now: the agent (idle), the job's connector (in this process), or nobody."""
        runner = self.runner
        if runner is not None and not runner.done:
            session = runner.session
            view = session.job_view() if session is not None else None
            return JobSource(view, self.cell.cameras, self.sim) if view is not None else None
        return IdleSource(self._arm_ports(), self.cell.cameras, self._bus, self._job_holds_bus, self.sim,
                          self._idle_cameras, self._idle_arms)

    def _close_telemetry_devices(self) -> None:
        """Run on the telemetry thread as it ends: no read of it is under way any more."""
        self._idle_cameras.close(wait_s=0.0)
        self._idle_arms.close()

    def _job_holds_bus(self) -> bool:
        runner = self.runner
        return runner is not None and not runner.done

    def _note_auto_reset(self, runner: JobRunner | None) -> None:
        """Keep the job's latest scripted reset for ``AutoResetWorking`` (one the interlock stopped says nothing)."""
        latest = runner.auto_reset_latest() if runner is not None else None
        if latest is not None and latest.get("outcome") != "stopped":
            self._auto_reset = latest

    def _completion_readiness(self) -> tuple[str | None, str] | None:
        """(why the cell's monitor cannot score or None, the reason) when the cell reports ``CompletionReady``.

        Reported when the monitor reads files on this host, and when it could never see
        the task: a simulated cell whose job pods' cameras draw no arm (the simulator runs
        in this agent, out of the pod's reach).
        """
        completion = self.cell.completion
        if completion is None:
            return None
        if self.cell.simulated and not self._cameras_draw_the_arm:
            return health.MONITOR_SEES_NO_ARM, "CannotSeeTheArm"
        models = self.deps.completion_models
        classifier = completion.classifier
        if classifier is not None and classifier.model_from is not None:  # not written to a file (yet)
            ref = classifier.model_from.config_map_key_ref
            why = models.problem(self.cell.name) if models is not None else None
            return why or f"ConfigMap {ref.name}: this node agent reads no ConfigMaps", "ConfigMapUnusable"
        if host_files(completion):
            problem = self._completion_files.problem(completion)
            source = models.source(self.cell.name) if models is not None else None
            if problem is not None and source is not None:
                problem = f"the model of {source} (the agent's copy; fix the ConfigMap): {problem}"
            return problem, "FileUnusable"
        return None

    def _heartbeat(self) -> None:
        streams = health.streams_condition(streams_probe(self.deps.link))
        try:
            conditions = (*health.cell_health(self.probe()), streams)
        except Exception:  # noqa: BLE001 - a probe bug must not stop the heartbeat; the others stay as they were
            log.warning("cell %s: health probe failed", self.cell.name, exc_info=True)
            conditions = (*health.cell_health(health.CellProbe(arms={}))[:1], streams)
        if self.cell.reset is not None and self.cell.reset.scripted:
            self._note_auto_reset(self.runner)
            conditions = (*conditions, health.auto_reset_condition(self._auto_reset))
        readiness = self._completion_readiness()
        if readiness is not None:
            conditions = (*conditions, health.completion_condition(*readiness))
        for _ in range(3):
            now = datetime.now(UTC)
            try:
                raw = self.deps.kube.read_cell(self.cell.name)
            except Gone:
                return
            current = (raw.get("status") or {}).get("conditions") or []
            merged = health.merge_conditions(current, conditions, now)
            if readiness is None:  # the settings taken out of the Cell take their condition with them
                remove_condition(merged, health.COMPLETION_READY)
            body = {
                "metadata": {"resourceVersion": raw["metadata"]["resourceVersion"]},
                "status": {"lastHeartbeatTime": status_time(now), "conditions": merged},
            }
            try:
                updated = self.deps.kube.patch_cell_status(self.cell.name, body)
                self.cell = resolved_cell(updated, self.deps.completion_models)
                return
            except Conflict:
                continue

    def _apply_sim_faults(self) -> None:
        if self.sim is None:
            return
        wanted = frozenset(
            item.strip() for item in self.cell.annotations.get(SIM_UNPLUG_ANNOTATION, "").split(",") if item.strip()
        )
        if wanted == self._unplugged:
            return
        for arm in self.sim.arms.values():
            arm.clear_faults()
        for item in wanted:
            arm_name, _, motor = item.rpartition("/")
            target = self.sim.arms.get(arm_name) if arm_name else next(iter(self.sim.arms.values()))
            if target is not None and motor in target.motors:
                target.unplug(motor)
        self._unplugged = wanted


