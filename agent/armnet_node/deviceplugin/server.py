"""The kubelet device-plugin API (v1beta1) for this host's cells: one gRPC server per cell.

The documented contract (kubernetes.io, "Device Plugins"): a plugin serves the
``DevicePlugin`` service on a unix socket of its own in the kubelet's
device-plugin directory, then calls ``Registration.Register`` on the kubelet's
``kubelet.sock`` there, naming its socket and resource. The kubelet then calls
``ListAndWatch`` (a stream of the devices and their health) and, for each
container requesting the resource, ``Allocate``. When the kubelet restarts it
removes every socket in the directory and recreates ``kubelet.sock``: the plugin
must notice and serve and register again. :class:`DevicePlugins` checks both
every ``check_s`` seconds (a socket of ours gone, a new ``kubelet.sock``).

The directory is ``/var/lib/kubelet/device-plugins`` whatever the kubelet's
``--root-dir`` (hard-coded in the kubelet). What to answer is decided in
``deviceplugin.decide``; this module reads the device facts and speaks gRPC.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent import futures
from pathlib import Path
from typing import Any

import grpc

from armnet_node.deviceplugin import decide
from armnet_node.deviceplugin.facts import read_fact
from armnet_node.deviceplugin.v1beta1 import api_pb2, api_pb2_grpc
from armnet_node.metrics import AgentMetrics

log = logging.getLogger(__name__)

DEVICE_PLUGIN_DIR = Path("/var/lib/kubelet/device-plugins")
KUBELET_SOCKET = "kubelet.sock"
API_VERSION = "v1beta1"
#: Seconds between health reads of a ListAndWatch stream, and between checks for a kubelet restart.
POLL_S = 1.0
REGISTER_TIMEOUT_S = 5.0

Paths = Callable[[], Sequence[decide.DevicePath]]
#: ``Healthy`` / ``Unhealthy`` from the agent's device watch of the cell (``node.device_watch``).
Health = Callable[[], str]


def _file_id(path: Path) -> tuple[int, int] | None:
    """Identity of a socket file (a recreated one differs), None if absent."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_ctime_ns


def _response(allocation: decide.Allocation) -> Any:
    return api_pb2.ContainerAllocateResponse(
        devices=[api_pb2.DeviceSpec(container_path=g.container_path, host_path=g.host_path,
                                    permissions=g.permissions) for g in allocation.devices],
        mounts=[api_pb2.Mount(container_path=g.container_path, host_path=g.host_path, read_only=g.read_only)
                for g in allocation.mounts],
    )


class CellPlugin(api_pb2_grpc.DevicePluginServicer):
    """The device plugin of one cell: its gRPC server, its registration, its answers."""

    def __init__(self, cell: str, paths: Paths, metrics: AgentMetrics, directory: Path = DEVICE_PLUGIN_DIR,
                 poll_s: float = POLL_S, health_source: Health | None = None) -> None:
        self.cell = cell
        #: The agent's verdict for the cell (the same one its ``HardwareReady`` and a running job's
        #: "device lost" follow); None: this plugin reads the paths itself (a plugin run alone).
        self.health_source = health_source
        self.resource = decide.resource_name(cell)
        self.socket = directory / decide.socket_name(cell)
        self.kubelet_socket = directory / KUBELET_SOCKET
        self.paths = paths
        self._metrics = metrics
        self._poll_s = poll_s
        self._server: grpc.Server | None = None
        self._served: tuple[int, int] | None = None
        self._registered_with: tuple[int, int] | None = None
        self._failing = False
        self._stop = threading.Event()

    # -- lifecycle (called by DevicePlugins, one thread) ------------------------------------

    @property
    def closed(self) -> bool:
        return self._stop.is_set()

    def ensure(self) -> None:
        """Serve if our socket is gone; register if the kubelet's socket is new since our registration."""
        if self.closed:
            return
        if self._server is None or _file_id(self.socket) != self._served:
            self._serve()
        kubelet = _file_id(self.kubelet_socket)
        if kubelet is None or kubelet == self._registered_with:
            return
        try:
            with grpc.insecure_channel(f"unix://{self.kubelet_socket}") as channel:
                api_pb2_grpc.RegistrationStub(channel).Register(api_pb2.RegisterRequest(
                    version=API_VERSION, endpoint=self.socket.name, resource_name=self.resource,
                    options=api_pb2.DevicePluginOptions()), timeout=REGISTER_TIMEOUT_S)
        except grpc.RpcError as exc:
            self._metrics.device_plugin_registrations.labels(cell=self.cell, result="failed").inc()
            # Once per failing spell (a stopped kubelet leaves its socket behind): retried every check.
            log.log(logging.DEBUG if self._failing else logging.WARNING,
                    "cell %s: registering %s with the kubelet failed (%s); retrying", self.cell, self.resource,
                    exc.details() if hasattr(exc, "details") else exc)
            self._failing = True
            return
        self._failing = False
        self._registered_with = kubelet
        self._metrics.device_plugin_registrations.labels(cell=self.cell, result="ok").inc()
        log.info("cell %s: device plugin registered with the kubelet as %s", self.cell, self.resource)

    def _serve(self) -> None:
        self._shutdown_server()
        self.socket.unlink(missing_ok=True)
        server = grpc.server(futures.ThreadPoolExecutor(max_workers=4, thread_name_prefix=f"armnet-dp-{self.cell}"))
        api_pb2_grpc.add_DevicePluginServicer_to_server(self, server)
        server.add_insecure_port(f"unix://{self.socket}")
        server.start()
        self._server = server
        self._served = _file_id(self.socket)
        self._registered_with = None  # a new socket: the kubelet must be told again

    def _shutdown_server(self) -> None:
        if self._server is not None:
            self._server.stop(grace=None)
            self._server = None

    def close(self) -> None:
        self._stop.set()
        self._shutdown_server()
        if _file_id(self.socket) == self._served:
            self.socket.unlink(missing_ok=True)
        if self.health_source is None:  # else the device watch owns the series
            with contextlib.suppress(KeyError):  # never reported: no series to remove
                self._metrics.device_healthy.remove(self.cell)

    # -- what the kubelet asks ---------------------------------------------------------------

    def facts(self) -> list[decide.DeviceFact]:
        return [read_fact(path) for path in self.paths()]

    def health(self) -> str:
        """The device's health for the kubelet: the agent's verdict for the cell when it has one.

        Why not the plugin's own read: the Cell's ``HardwareReady`` and the running job
        follow the agent's debounced verdict, and the kubelet must not be told otherwise.
        """
        if self.health_source is not None:
            return self.health_source()
        state = decide.health(self.facts())
        self._metrics.device_healthy.labels(cell=self.cell).set(1 if state == decide.HEALTHY else 0)
        return state

    def GetDevicePluginOptions(self, request: Any, context: Any) -> Any:  # noqa: N802 - the gRPC method name
        return api_pb2.DevicePluginOptions()

    def ListAndWatch(self, request: Any, context: Any) -> Iterator[Any]:  # noqa: N802
        """The one device (id: the cell's name), sent again whenever its health changes."""
        last: str | None = None
        while context.is_active() and not self._stop.is_set():
            state = self.health()
            if state != last:
                if last is not None:
                    log.warning("cell %s: device %s -> %s", self.cell, last, state)
                last = state
                yield api_pb2.ListAndWatchResponse(devices=[api_pb2.Device(ID=self.cell, health=state)])
            self._stop.wait(self._poll_s)

    def Allocate(self, request: Any, context: Any) -> Any:  # noqa: N802
        responses = []
        for _ in request.container_requests:
            try:
                allocation = decide.allocate(self.facts())
            except decide.AllocationRefused as exc:
                self._metrics.device_plugin_allocations.labels(cell=self.cell, result="refused").inc()
                log.warning("cell %s: allocation refused: %s", self.cell, exc)
                # abort raises: the kubelet fails the pod's admission with this message.
                context.abort(grpc.StatusCode.FAILED_PRECONDITION, f"cell {self.cell}: {exc}")
                raise  # not reached
            responses.append(_response(allocation))
            self._metrics.device_plugin_allocations.labels(cell=self.cell, result="granted").inc()
        return api_pb2.AllocateResponse(container_responses=responses)

    def GetPreferredAllocation(self, request: Any, context: Any) -> Any:  # noqa: N802
        return api_pb2.PreferredAllocationResponse()

    def PreStartContainer(self, request: Any, context: Any) -> Any:  # noqa: N802
        return api_pb2.PreStartContainerResponse()


class DevicePlugins:
    """The device plugins of this host's cells: started and stopped with the cells, kept registered."""

    def __init__(self, metrics: AgentMetrics, directory: Path = DEVICE_PLUGIN_DIR, check_s: float = POLL_S) -> None:
        self.metrics = metrics
        self.directory = directory
        self.check_s = check_s
        self._plugins: dict[str, CellPlugin] = {}
        #: Guards ``_plugins``; held briefly, never across a call to the kubelet.
        self._lock = threading.Lock()
        #: One ``ensure`` at a time (a plugin's lifecycle is single-threaded): the check loop's, or a
        #: new cell's in ``sync``. A kubelet that accepts but never answers costs a new cell's pass
        #: a few seconds, never every pass of every cell (the agent's heartbeats run in those passes).
        self._ensure_lock = threading.Lock()
        self._refused: set[str] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="armnet-device-plugins", daemon=True)

    def start(self) -> DevicePlugins:
        self._thread.start()
        return self

    def resource(self, cell: str) -> str:
        return decide.resource_name(cell)

    def sync(self, cells: Mapping[str, Paths], health: Mapping[str, Health] | None = None) -> None:
        """One plugin per cell in ``cells`` (a new one served and registered now), none for the others.

        ``health``: the agent's device verdict per cell, which the plugin then reports as it is.
        """
        health = health or {}
        added: list[CellPlugin] = []
        removed: list[CellPlugin] = []
        with self._lock:
            for name in [n for n in self._plugins if n not in cells]:
                log.info("cell %s: its device plugin stops", name)
                removed.append(self._plugins.pop(name))
            for name, paths in cells.items():
                if name in self._plugins:
                    self._plugins[name].paths = paths  # the cell's current worker says where its devices are
                    self._plugins[name].health_source = health.get(name)
                    continue
                try:
                    plugin = CellPlugin(name, paths, self.metrics, self.directory, self.check_s, health.get(name))
                except ValueError as exc:
                    if name not in self._refused:  # said once, not on every pass
                        self._refused.add(name)
                        log.error("%s", exc)
                    continue
                self._plugins[name] = plugin
                added.append(plugin)
        with self._ensure_lock:
            for plugin in removed:
                plugin.close()
            for plugin in added:  # before any launch: a job pod's connector requests the resource
                self._ensure(plugin)

    def _ensure(self, plugin: CellPlugin) -> None:
        try:
            plugin.ensure()
        except Exception:  # noqa: BLE001 - the directory may be missing (no kubelet yet): retried next check
            log.warning("cell %s: device plugin not served", plugin.cell, exc_info=True)

    def _loop(self) -> None:
        while not self._stop.wait(self.check_s):
            with self._lock:
                plugins = list(self._plugins.values())
            with self._ensure_lock:
                for plugin in plugins:
                    if not plugin.closed:
                        self._ensure(plugin)

    def stop(self) -> None:
        self._stop.set()
        with self._lock:
            plugins = list(self._plugins.values())
            self._plugins.clear()
        with self._ensure_lock:
            for plugin in plugins:
                plugin.close()
