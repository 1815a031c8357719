"""``NodeAgent``: the level-based loop of one robot host.

Every pass reads the Cells of this node, the RobotJobs and the job containers
on the engine (by label), and hands each cell's worker what concerns it. Watches
on Cells and RobotJobs only wake the loop early; correctness comes from the
pass, so a missed event costs at most one ``pass_period``. The engine is listed
at most once a ``pass_period`` (see ``NodeAgent._containers``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from armnet_core.api import GROUP, VERSION
from armnet_core.backoff import BackoffPolicy
from armnet_core.cell_completion import DEFAULT_COMPLETION_DIRS
from armnet_launch.plan import LABEL_CELL, LABEL_NAMESPACE

from armnet_node.artifacts import ObjectStore
from armnet_node.completion_configmap import ConfigMapModels, resolved_cell
from armnet_node.deviceplugin.server import DevicePlugins
from armnet_node.kube import AgentKube, KubeError
from armnet_node.launchers import JobLauncher, PodLauncher
from armnet_node.metrics import AgentMetrics
from armnet_node.model import Cell, Job, parse_job
from armnet_node.plan import HostPaths
from armnet_node.publish import Link
from armnet_node.runner import RunnerDeps
from armnet_node.telemetry import TelemetrySettings
from armnet_node.uploads import UploadQueue
from armnet_node.worker import CellWorker, WorkerSettings

log = logging.getLogger(__name__)

#: A watch that failed (the API server away, a watch refused): reconnected after 1 s, doubling, at most
#: 30 s apart. A watch only wakes the pass early, and the pass runs every ``pass_period`` regardless, so a
#: slow reconnect costs latency, never a missed change; an API server that is away is not asked every second.
WATCH_BACKOFF = BackoffPolicy(first_s=1.0, max_s=30.0)


@dataclass(frozen=True)
class AgentSettings:
    node_name: str
    state_dir: Path
    namespaces: tuple[str, ...] = ()
    heartbeat_period: float = 5.0
    telemetry: TelemetrySettings = field(default_factory=TelemetrySettings)
    pass_period: float = 2.0
    dev_mounts: tuple[str, ...] = ()
    dev_env: dict[str, str] = field(default_factory=dict)
    completion_dirs: tuple[str, ...] = DEFAULT_COMPLETION_DIRS
    #: The namespace of the ConfigMaps Cells name (classifier models): the agent's own; None: it has none.
    config_namespace: str | None = None


class NodeAgent:
    def __init__(
        self, settings: AgentSettings, kube: AgentKube, launcher: JobLauncher, metrics: AgentMetrics, link: Link,
        device_plugins: DevicePlugins | None = None, store: ObjectStore | None = None,
    ) -> None:
        """``store``: where ended jobs' outputs go (None: they are removed with the job)."""
        self.settings = settings
        #: The kubelet device plugins of the cells (pod launcher), kept in step with the workers each pass.
        self.device_plugins = device_plugins
        self.kube = kube
        self.launcher = launcher
        self.metrics = metrics
        self.link = link
        paths = HostPaths(settings.state_dir, settings.dev_mounts, settings.dev_env or None, settings.completion_dirs)
        self.uploads = UploadQueue(store, paths, kube, metrics)
        models = ConfigMapModels(kube, settings.config_namespace, paths.completion_models_dir)
        self.deps = RunnerDeps(kube=kube, launcher=launcher, paths=paths, metrics=metrics, link=link,
                               uploads=self.uploads, completion_models=models)
        self.workers: dict[str, CellWorker] = {}
        self._wake = threading.Event()
        self._rows: dict[str, Any] | None = None
        self._rows_listed_at = 0.0

    def run(self, stop: threading.Event) -> None:
        log.info("node agent for node %s started", self.settings.node_name)
        for plural in ("cells", "robotjobs"):
            threading.Thread(target=self._watch, args=(plural, stop), name=f"armnet-watch-{plural}",
                             daemon=True).start()
        threading.Thread(target=self.uploads.run, args=(stop,), name="armnet-uploads", daemon=True).start()
        while not stop.is_set():
            try:
                self.pass_once()
            except Exception:  # noqa: BLE001 - a failed pass is retried; the agent never dies of one
                log.warning("agent pass failed", exc_info=True)
            # Not a retry backoff: the pass is periodic, failed or not (a change wakes it early).
            self._wake.wait(self.settings.pass_period)
            self._wake.clear()
        for worker in self.workers.values():
            worker.stop()

    def _devices_through_plugin(self, worker: CellWorker) -> bool:
        if not isinstance(self.launcher, PodLauncher):
            return True
        return self.launcher.settings.devices_through_plugin(simulated=worker.sim is not None)

    def pass_once(self) -> None:
        cells = self._my_cells()
        for name, cell in cells.items():
            worker = self.workers.get(name)
            if worker is None:
                worker = self.workers[name] = CellWorker(
                    cell, self.deps, WorkerSettings(self.settings.heartbeat_period, self.settings.telemetry)
                ).start()
            worker.update(cell)
        for name in [n for n in self.workers if n not in cells]:
            log.info("cell %s is gone or moved to another node; its worker stops", name)
            self.workers.pop(name).stop()
        if self.deps.completion_models is not None:  # after the stops: no heartbeat of a gone cell writes again
            self.deps.completion_models.retain(cells)
        if self.device_plugins is not None:
            # Before any launch: a job pod's connector requests the resource the plugin registers.
            # The plugin reports each cell's device watch verdict: the kubelet, the Cell's
            # HardwareReady and the running job see one health.
            served = {name: worker for name, worker in self.workers.items() if self._devices_through_plugin(worker)}
            self.device_plugins.sync({name: worker.device_paths for name, worker in served.items()},
                                     {name: worker.devices.plugin_health for name, worker in served.items()})
        jobs = self._jobs()
        containers = self._containers()
        for worker in self.workers.values():
            worker.observe(jobs, containers)
        self._remove_orphans(jobs, containers)

    def _my_cells(self) -> dict[str, Cell]:
        cells = {}
        for obj in self.kube.list_cells():
            if (obj.get("spec") or {}).get("nodeName") != self.settings.node_name:
                continue
            try:
                cell = resolved_cell(obj, self.deps.completion_models)
            except ValueError as exc:
                log.warning("%s", exc)
                continue
            cells[cell.name] = cell
        return cells

    def _jobs(self) -> list[Job]:
        jobs = []
        for obj in self.kube.list_jobs():
            try:
                jobs.append(parse_job(obj))
            except ValueError as exc:
                log.warning("%s", exc)
        return jobs

    def _containers(self) -> dict[str, Any]:
        """Job uid -> the launcher's row of its container or pod; one list call a pass period at most.

        A pass runs on every watch event too, several a second while jobs report, and
        Podman answers each list by asking the OCI runtime for the state of every running
        container (a ``runc`` process each): listed on every pass, the engine's lists took
        a third of a core of the suite's two. The rows serve adoption and orphan removal,
        which a pass period's delay does not harm: a running job's worker follows its own
        container, never the list.
        """
        now = time.monotonic()
        if self._rows is None or now - self._rows_listed_at >= self.settings.pass_period:
            self._rows = self.launcher.running()
            self._rows_listed_at = now
        return self._rows

    def _remove_orphans(self, jobs: list[Job], containers: dict[str, Any]) -> None:
        """A container of one of this node's cells whose RobotJob no longer exists.

        Only this node's cells: another agent may share the engine (its jobs are
        not in this agent's lists), and its containers are none of our business.
        """
        known = {job.uid for job in jobs}
        running = {w.runner.uid for w in self.workers.values() if w.runner is not None}
        for uid, row in containers.items():
            labels = self.launcher.row_labels(row)
            namespace = labels.get(LABEL_NAMESPACE, "")
            mine = labels.get(LABEL_CELL) in self.workers
            watched = not self.settings.namespaces or namespace in self.settings.namespaces
            if uid in known or uid in running or not watched or not mine:
                continue
            log.warning("removing the %s of job uid %s: its RobotJob no longer exists", self.launcher.kind, uid)
            try:
                self.launcher.remove(row)
            except Exception:  # noqa: BLE001 - gone already
                log.debug("orphan removal failed", exc_info=True)

    def _watch(self, plural: str, stop: threading.Event) -> None:
        """Wake the pass on any change; reconnect on errors (the pass is the source of truth)."""
        from kubernetes import watch

        list_call: Callable[..., Any]
        if plural == "cells" or not self.kube.namespaces:
            list_call = self.kube.custom.list_cluster_custom_object
            args: tuple[Any, ...] = (GROUP, VERSION, plural)
        else:
            return  # namespace-limited agents rely on the pass for jobs
        backoff = WATCH_BACKOFF.start()
        while not stop.is_set():
            try:
                stream = watch.Watch().stream(list_call, *args, timeout_seconds=30)  # type: ignore[no-untyped-call]
                for _event in stream:
                    backoff.succeeded()
                    self._wake.set()
                    if stop.is_set():
                        return
            except (KubeError, Exception):  # noqa: BLE001 - reconnect after a pause
                delay = backoff.failed()
                log.debug("watch on %s ended; reconnecting in %.0f s", plural, delay, exc_info=True)
                stop.wait(delay)
            else:
                backoff.succeeded()  # the watch's own timeout: reconnect at once
