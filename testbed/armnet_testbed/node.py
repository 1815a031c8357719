"""A real Kubernetes node for tests: containerd + kubelet registered with the control plane.

Facts and settings come from docs/reference/testbed-host.md, "A real node" (a working trial on
this machine kind): Debian's containerd 1.6 and runc, a kubelet built by
scripts/setup.d/30-k8s.sh, a local pause image (scripts/setup.d/45-pause-image.sh),
images imported without a registry (``podman save`` -> ``ctr images import``).

Host changes and how they are undone (``stop()``; also after a crashed run):

- containerd and kubelet state live in a temporary directory of their own
  (containerd state/socket, runc root, kubelet root dir, pod logs); the mounts
  the kubelet and containerd leave there are unmounted before removal. Only
  containerd's root (its content store and unpacked snapshots: an image cache,
  like Podman's storage) persists, in ``~/.cache/armnet/node/containerd``, so a
  warm start imports nothing; the containers in it are deleted at stop.
- the node IP is an address the test bed adds to ``lo`` (the kubelet refuses
  127.0.0.0/8 as node IP); nothing leaves the machine.
- pods get an isolated network: a bridge the test bed creates (``armnet-node0``,
  removed at stop) with no address on the host, no gateway, no masquerade and
  no routes, so a pod reaches only other pods of this node. (A loopback-only CNI
  config is not enough: containerd 1.6 fails every sandbox with "failed to find
  network info" when the result has no ``eth0``.)
- the sysctls the kubelet sets (``kernel.panic`` ...) are saved and restored.
- no iptables changes: ``makeIPTablesUtilChains: false``.
- the ``kubepods`` cgroups, ``/var/log/containers`` links, ``/run/containerd/s``
  shim sockets and CNI result files this node made are removed.

Only one test-bed node can run on a host at a time (kubepods cgroups, sysctls and
``/var/log/containers`` are host-wide): a second one waits for the first.

Two optional overrides, for experiments (unset: the behaviour above):

- ``ARMNET_TESTBED_CONTAINERD``: path of another containerd binary. A containerd 2
  (``containerd --version``) gets a schema-3 config of the same settings, the
  ``containerd-shim-runc-v2`` next to the binary if there is one, and by default a
  root of its own, ``<root>-v2`` (it migrates the metadata database to a version
  containerd 1.6 does not read); ``ARMNET_NODE_CONTAINERD_ROOT`` still wins.
- ``ARMNET_TESTBED_KUBELET_FEATURE_GATES``: ``--feature-gates`` syntax (e.g.
  ``EventedPLEG=true``, which needs containerd 2's CRI events), written to the
  kubelet config's ``featureGates`` (the flag is deprecated).
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import signal
import ssl
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import yaml

from armnet_testbed.containerd import (
    CONTAINERD_ROOT,
    PAUSE_IMAGE,
    Containerd,
    hold_node_lock,
    proc_cmdline,
    release_node_lock,
    shim_pids,
)
from armnet_testbed.errors import TestbedSetupError
from armnet_testbed.images import BASE_IMAGE
from armnet_testbed.kube import KUBELET_CLIENT_USER, ControlPlane, k8s_bin_dir
from armnet_testbed.procs import ManagedProcess, free_port, progress, require_tool, wait_until

NODE_NAME = "armnet-node"
# RFC 2544 benchmarking range: never routed on the internet, put on `lo` here.
NODE_IP = "198.18.0.10"
CNI_NETWORK = "armnet-node"
POD_BRIDGE = "armnet-node0"
POD_SUBNET = "198.18.128.0/24"
# Experiment override (module docstring); unset by default.
FEATURE_GATES_ENV = "ARMNET_TESTBED_KUBELET_FEATURE_GATES"
# What the kubelet changes with protectKernelDefaults=false (pkg/kubelet/cm
# setupKernelTunables); saved before it starts, restored after it stops.
KUBELET_SYSCTLS = (
    "vm/overcommit_memory", "vm/panic_on_oom", "kernel/panic", "kernel/panic_on_oops",
    "kernel/keys/root_maxkeys", "kernel/keys/root_maxbytes",
)
HOST_STATE = Path("/run/lock/armnet-testbed-node.state.json")
CONTAINER_LOGS_DIR = Path("/var/log/containers")  # hard-coded in the kubelet
SHIM_SOCKET_DIR = Path("/run/containerd/s")  # hard-coded in containerd 1.6
CNI_RESULTS = Path("/var/lib/cni/results")
NETNS_DIR = Path("/var/run/netns")
# Hard-coded in the kubelet whatever --root-dir says: the device-plugin socket
# directory (kubelet.sock and its checkpoint). Removed at stop if we created it.
KUBELET_HOST_DIR = Path("/var/lib/kubelet")
DEVICE_PLUGIN_DIR = KUBELET_HOST_DIR / "device-plugins"


# ---------------------------------------------------------------------- config files
def feature_gates(value: str) -> dict[str, bool]:
    """``--feature-gates`` syntax (``A=true,B=false``) as the config's ``featureGates`` map."""
    gates = {}
    for item in filter(None, (part.strip() for part in value.split(","))):
        name, sep, flag = item.partition("=")
        if not sep or flag.strip().lower() not in ("true", "false"):
            raise TestbedSetupError(f"{FEATURE_GATES_ENV}: {item!r} is not NAME=true|false")
        gates[name.strip()] = flag.strip().lower() == "true"
    return gates


def pod_network_config(ipam_dir: Path) -> dict[str, Any]:
    """An isolated pod network: a host bridge without address, gateway, NAT or routes."""
    return {"cniVersion": "0.4.0", "name": CNI_NETWORK, "plugins": [{
        "type": "bridge", "bridge": POD_BRIDGE, "isGateway": False, "isDefaultGateway": False,
        "ipMasq": False, "hairpinMode": False,
        "ipam": {"type": "host-local", "dataDir": str(ipam_dir),
                 "ranges": [[{"subnet": POD_SUBNET}]]},
    }]}


def kubelet_config(*, socket: Path, node_ip: str, port: int, healthz_port: int,
                   ca_cert: Path, tls_cert: Path, tls_key: Path, pod_logs: Path,
                   gates: dict[str, bool] | None = None) -> dict[str, Any]:
    """The KubeletConfiguration; each setting is explained in docs/testing.md.

    ``gates`` (the feature-gate override) becomes ``featureGates``; none by default.
    """
    config: dict[str, Any] = {
        "apiVersion": "kubelet.config.k8s.io/v1beta1",
        "kind": "KubeletConfiguration",
        "containerRuntimeEndpoint": f"unix://{socket}",
        "cgroupDriver": "cgroupfs",
        "failCgroupV1": False,
        "failSwapOn": False,
        "oomScoreAdj": 0,
        "maxOpenFiles": 16384,
        "address": node_ip,
        "port": port,
        "readOnlyPort": 0,
        "healthzBindAddress": "127.0.0.1",
        "healthzPort": healthz_port,
        "tlsCertFile": str(tls_cert),
        "tlsPrivateKeyFile": str(tls_key),
        "authentication": {
            "anonymous": {"enabled": False},
            "webhook": {"enabled": True, "cacheTTL": "30s"},
            "x509": {"clientCAFile": str(ca_cert)},
        },
        "authorization": {"mode": "Webhook"},
        "evictionHard": {"memory.available": "100Mi", "nodefs.available": "1%",
                         "imagefs.available": "1%", "nodefs.inodesFree": "1%"},
        "imageGCHighThresholdPercent": 100,
        "imageGCLowThresholdPercent": 99,
        "makeIPTablesUtilChains": False,
        "resolvConf": "/etc/resolv.conf",
        "podLogsDir": str(pod_logs),
        "serializeImagePulls": False,
        "registerNode": True,
    }
    if gates:
        config["featureGates"] = gates
    return config


# ---------------------------------------------------------------------- host state
def read_sysctls() -> dict[str, str]:
    return {name: (Path("/proc/sys") / name).read_text().strip() for name in KUBELET_SYSCTLS}


def write_sysctls(values: dict[str, str]) -> None:
    for name, value in values.items():
        path = Path("/proc/sys") / name
        with contextlib.suppress(OSError):
            if path.read_text().strip() != value:
                path.write_text(value)


def mounts_under(root: Path) -> list[str]:
    """Mount points at or below ``root``, deepest (last mounted) first."""
    found = []
    prefix = str(root).rstrip("/")
    for line in Path("/proc/self/mountinfo").read_text().splitlines():
        point = line.split()[4].replace("\\040", " ")
        if point == prefix or point.startswith(prefix + "/"):
            found.append(point)
    return list(reversed(found))


def unmount_all(root: Path) -> None:
    for _ in range(5):  # the kubelet's self bind mount can be stacked
        points = mounts_under(root)
        if not points:
            return
        for point in points:
            if subprocess.run(["umount", point], capture_output=True, check=False).returncode:
                subprocess.run(["umount", "-l", point], capture_output=True, check=False)


def remove_cgroup_tree(name: str) -> None:
    """rmdir ``/sys/fs/cgroup/<hierarchy>/<name>`` depth-first in every hierarchy."""
    for hierarchy in Path("/sys/fs/cgroup").iterdir():
        top = hierarchy / name
        if not top.is_dir():
            continue
        for dirpath, _dirs, _files in sorted(os.walk(top), key=lambda w: -len(w[0])):
            with contextlib.suppress(OSError):
                os.rmdir(dirpath)


def remove_empty_dirs(top: Path) -> None:
    """rmdir ``top`` and its subdirectories bottom-up; anything not empty stays."""
    if not top.is_dir():
        return
    for dirpath, _dirs, _files in os.walk(top, topdown=False):
        with contextlib.suppress(OSError):
            os.rmdir(dirpath)


# ---------------------------------------------------------------------- the node
@dataclass
class Node:
    """containerd + kubelet on this host, registered as Node ``name`` with ``plane``."""

    plane: ControlPlane
    name: str = NODE_NAME
    node_ip: str = NODE_IP
    images: tuple[str, ...] = (BASE_IMAGE,)
    workdir: Path | None = None
    ready_timeout: float = 60.0
    lock_timeout: float = 600.0

    kubelet_log: Path = Path()
    containerd: Containerd | None = None
    _procs: list[ManagedProcess] = field(default_factory=list)
    _lock: TextIO | None = None
    _host: dict[str, Any] = field(default_factory=dict)
    _owns_workdir: bool = False

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Node:
        started = time.monotonic()
        if os.geteuid() != 0:
            raise PermissionError("the test-bed node needs root (containerd, kubelet, cgroups): "
                                  "run the node tests / armnet dev up as root, or --no-node")
        bins = k8s_bin_dir()
        kubelet = require_tool("kubelet", bins / "kubelet")
        require_tool("runc")
        require_tool("podman")
        if not Path("/usr/lib/cni/loopback").is_file():
            raise TestbedSetupError("the CNI plugins are missing (/usr/lib/cni/loopback)")
        for image in (PAUSE_IMAGE, *self.images):
            if subprocess.run(["podman", "image", "exists", image], check=False).returncode:
                raise TestbedSetupError(f"image {image} is not in podman")
        self._lock = hold_node_lock(self.lock_timeout)
        if self.workdir is None:
            self.workdir = Path(tempfile.mkdtemp(prefix="armnet-node-"))
            self._owns_workdir = True
        try:
            self._start(kubelet)
        except BaseException:
            self.stop()
            raise
        progress(f"node {self.name} Ready in {time.monotonic() - started:.1f} s")
        return self

    def _start(self, kubelet: str) -> None:
        assert self.workdir is not None and self.plane.pki is not None
        w = self.workdir
        self._save_host_state()

        cni_dir = w / "cni"
        cni_dir.mkdir()
        (cni_dir / "10-armnet-node.conflist").write_text(
            json.dumps(pod_network_config(w / "cni-ipam")))
        self.containerd = Containerd(w).start(cni_dir, track=self._track)
        self._host["containerd_root"] = str(self.containerd.root)
        HOST_STATE.write_text(json.dumps(self._host))

        t0 = time.monotonic()
        imported = self.import_images(PAUSE_IMAGE, *self.images)
        progress(f"images: {len(imported)} imported ({', '.join(imported) or 'all cached'}) "
                 f"in {time.monotonic() - t0:.1f} s")

        t0 = time.monotonic()
        pki = self.plane.pki
        node_user = f"system:node:{self.name}"
        cert, key = pki.client_cert(node_user, ("system:nodes",))
        tls_cert, tls_key = pki.serving_cert(self.name, (self.node_ip,), (self.name,))
        kubeconfig = self._write_kubeconfig(cert, key)
        self.plane.kubectl("create", "clusterrolebinding", "armnet-apiserver-kubelet-admin",
                           "--clusterrole=system:kubelet-api-admin",
                           f"--user={KUBELET_CLIENT_USER}", check=False)
        config = kubelet_config(socket=self.socket, node_ip=self.node_ip, port=free_port(),
                                healthz_port=free_port(), ca_cert=pki.ca_cert, tls_cert=tls_cert,
                                tls_key=tls_key, pod_logs=w / "pod-logs",
                                gates=feature_gates(os.environ.get(FEATURE_GATES_ENV, "")))
        (w / "kubelet.yaml").write_text(yaml.safe_dump(config))
        self.kubelet_log = w / "kubelet.log"
        kubelet_proc = ManagedProcess("kubelet", [
            kubelet, f"--config={w / 'kubelet.yaml'}", f"--kubeconfig={kubeconfig}",
            f"--root-dir={self.kubelet_root_dir}", f"--hostname-override={self.name}",
            f"--node-ip={self.node_ip}", "--v=1",
        ], self.kubelet_log)
        self._track(kubelet_proc)
        wait_until(self.is_ready, timeout=self.ready_timeout, interval=0.3,
                   what=f"node {self.name} Ready", alive=kubelet_proc.ensure_running)
        progress(f"kubelet registered {self.name} Ready in {time.monotonic() - t0:.1f} s")

    def stop(self) -> None:
        """Stop pods, kubelet and containerd, then undo every host change; safe twice."""
        try:
            if self._procs:
                self._drain()
                for proc in reversed(self._procs):
                    if self.containerd is not None and proc is self.containerd.process:
                        self.containerd.stop()
                    proc.stop()
                self._procs.clear()
            self._restore_host_state()
            if self.containerd is not None:
                unmount_all(self.containerd.root)
            if self._owns_workdir and self.workdir is not None:
                unmount_all(self.workdir)
                shutil.rmtree(self.workdir, ignore_errors=True)
        finally:
            if self._lock is not None:
                release_node_lock(self._lock)
                self._lock = None

    def __enter__(self) -> Node:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def restart_kubelet(self) -> None:
        """Stop the kubelet and start it again with the same flags (pods keep running).

        Returns once the new kubelet serves its device-plugin registration socket
        (it removes the directory's other sockets first: plugins must register again).
        """
        old = next(p for p in self._procs if p.name == "kubelet")
        registration = DEVICE_PLUGIN_DIR / "kubelet.sock"

        def identity() -> tuple[int, int] | None:
            with contextlib.suppress(OSError):
                st = registration.stat()
                return st.st_ino, st.st_ctime_ns
            return None

        before = identity()
        old.stop()
        self._procs.remove(old)
        proc = ManagedProcess("kubelet", old.argv, self.kubelet_log)
        self._track(proc)
        wait_until(lambda: identity() not in (None, before), timeout=30,
                   interval=0.2, what="the restarted kubelet's device-plugin socket", alive=proc.ensure_running)

    # ------------------------------------------------------------------ images
    @property
    def kubelet_root_dir(self) -> Path:
        """The kubelet's ``--root-dir`` (the chart's ``agent.kubeletRootDir`` on this node)."""
        assert self.workdir is not None
        return self.workdir / "kubelet"

    @property
    def started_containerd(self) -> Containerd:
        """The node's containerd; an error before ``start()``."""
        assert self.containerd is not None, "the node is not started"
        return self.containerd

    @property
    def socket(self) -> Path:
        """containerd's API socket (``ctr --address``)."""
        return self.started_containerd.socket

    @property
    def containerd_log(self) -> Path:
        return self.started_containerd.log

    def import_image(self, image: str) -> bool:
        """Make a Podman image available to pods (``imagePullPolicy: Never``), same name.

        Skipped when the node already has it from the same Podman image id (the
        image cache persists); returns whether it imported.
        """
        return bool(self.import_images(image))

    def import_images(self, *images: str) -> list[str]:
        """Import the images the node lacks (in one archive: testbed/armnet_testbed/containerd.py); return those imported."""
        return self.started_containerd.import_images(*images)

    def drop_unnamed_images(self) -> list[str]:
        return self.started_containerd.drop_unnamed_images()

    def forget_images(self, stale: Callable[[str], bool]) -> list[str]:
        """Remove the named images ``stale`` picks, and the content only they held."""
        return self.started_containerd.forget_images(stale)

    def ctr(self, *args: str, check: bool = True, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        """``ctr`` against this node's containerd, namespace ``k8s.io`` (the CRI's)."""
        return self.started_containerd.ctr(*args, check=check, timeout=timeout)

    # ------------------------------------------------------------------ status
    def api_get(self, path: str) -> dict[str, Any] | None:
        """GET ``path`` from the apiserver as admin; None if it does not exist."""
        request = urllib.request.Request(f"{self.plane.url}{path}")
        request.add_header("Authorization", f"Bearer {self.plane.admin_token}")
        assert self.plane.pki is not None
        context = ssl.create_default_context(cafile=str(self.plane.pki.ca_cert))
        try:
            with urllib.request.urlopen(request, timeout=5, context=context) as response:
                return dict(json.load(response))
        except urllib.error.HTTPError as exc:
            if exc.code == 404:
                return None
            raise

    def node_object(self) -> dict[str, Any] | None:
        return self.api_get(f"/api/v1/nodes/{self.name}")

    def wait_for_pod(self, namespace: str, name: str, *,
                     phases: tuple[str, ...] = ("Succeeded", "Failed"),
                     timeout: float = 90.0) -> dict[str, Any]:
        """The pod once its phase is one of ``phases``; on timeout, an error with its status."""
        deadline = time.monotonic() + timeout
        pod: dict[str, Any] | None = None
        while time.monotonic() < deadline:
            pod = self.api_get(f"/api/v1/namespaces/{namespace}/pods/{name}")
            if pod is not None and pod.get("status", {}).get("phase") in phases:
                return pod
            time.sleep(0.5)
        status = json.dumps((pod or {}).get("status"), indent=1)[:3000]
        raise TimeoutError(f"pod {namespace}/{name} not in {phases} after {timeout:.0f} s; "
                           f"status: {status}; kubelet log: {self.kubelet_log}")

    def is_ready(self) -> bool:
        node = self.node_object()
        conditions = (node or {}).get("status", {}).get("conditions", [])
        return any(c["type"] == "Ready" and c["status"] == "True" for c in conditions)

    def pod_yaml(self, name: str, **overrides: Any) -> dict[str, Any]:
        """A pod skeleton bound to this node: ``spec.nodeName``, no cluster DNS, no token."""
        spec: dict[str, Any] = {"nodeName": self.name, "dnsPolicy": "Default",
                                "automountServiceAccountToken": False,
                                "restartPolicy": "Never", "terminationGracePeriodSeconds": 5}
        spec.update(overrides)
        return {"apiVersion": "v1", "kind": "Pod", "metadata": {"name": name}, "spec": spec}

    # ------------------------------------------------------------------ internals
    def _write_kubeconfig(self, cert: Path, key: Path) -> Path:
        assert self.workdir is not None and self.plane.pki is not None
        config = {
            "apiVersion": "v1", "kind": "Config", "current-context": "node",
            "clusters": [{"name": "armnet", "cluster": {
                "server": self.plane.url,
                "certificate-authority-data": base64.b64encode(
                    self.plane.pki.ca_cert.read_bytes()).decode()}}],
            "users": [{"name": "node", "user": {"client-certificate": str(cert),
                                                 "client-key": str(key)}}],
            "contexts": [{"name": "node", "context": {"cluster": "armnet", "user": "node"}}],
        }
        path = self.workdir / "kubelet.kubeconfig"
        path.write_text(yaml.safe_dump(config))
        path.chmod(0o600)
        return path

    def _save_host_state(self) -> None:
        """Record what the node changes; a state file left by a crashed run wins."""
        if HOST_STATE.is_file():
            progress(f"a previous test-bed node did not clean up ({HOST_STATE}); undoing it")
            self._host = json.loads(HOST_STATE.read_text())
            self._clean_up_after_crash()
            self._restore_host_state()
        self._host = {
            "sysctls": read_sysctls(),
            "node_ip": self.node_ip,
            "netns_before": sorted(p.name for p in NETNS_DIR.glob("*")) if NETNS_DIR.is_dir()
            else [],
            "created": [str(p) for p in (CONTAINER_LOGS_DIR, SHIM_SOCKET_DIR.parent, NETNS_DIR,
                                         KUBELET_HOST_DIR, CNI_RESULTS.parent) if not p.exists()],
            "pod_logs": str(self.workdir / "pod-logs") if self.workdir else "",
            "workdir": str(self.workdir) if self.workdir else "",
            "owns_workdir": self._owns_workdir,
        }
        HOST_STATE.write_text(json.dumps(self._host))
        added = subprocess.run(["ip", "addr", "add", f"{self.node_ip}/32", "dev", "lo"],
                               capture_output=True, text=True, check=False)
        if added.returncode and "File exists" not in added.stderr:
            raise RuntimeError(f"adding {self.node_ip} to lo failed: {added.stderr.strip()}")
        # The pod bridge, made here (the CNI plugin reuses it) so that it has no
        # IPv6 link-local address either: the host gets no address on the pod network.
        bridge = subprocess.run(["ip", "link", "add", POD_BRIDGE, "type", "bridge"],
                                capture_output=True, text=True, check=False)
        if bridge.returncode and "File exists" not in bridge.stderr:
            raise RuntimeError(f"creating bridge {POD_BRIDGE} failed: {bridge.stderr.strip()}")
        with contextlib.suppress(OSError):
            Path(f"/proc/sys/net/ipv6/conf/{POD_BRIDGE}/disable_ipv6").write_text("1")

    def _track(self, proc: ManagedProcess) -> None:
        """Remember a started process, also on disk for the run after a crash."""
        self._procs.append(proc)
        self._host.setdefault("procs", []).append([proc.proc.pid, proc.argv])
        HOST_STATE.write_text(json.dumps(self._host))

    def _clean_up_after_crash(self) -> None:
        """Processes and mounts a killed run left: only those it recorded as its own."""
        for pid, argv in self._host.get("procs", []):
            if proc_cmdline(pid)[:len(argv)] == argv:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
        old_workdir = self._host.get("workdir")
        if old_workdir:
            for pid in shim_pids(Path(old_workdir) / "containerd.sock"):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
            time.sleep(0.5)
            unmount_all(Path(old_workdir))
            unmount_all(Path(self._host.get("containerd_root", CONTAINERD_ROOT)))
            if self._host.get("owns_workdir"):
                shutil.rmtree(old_workdir, ignore_errors=True)

    def _restore_host_state(self) -> None:
        host = self._host
        if not host:
            return
        write_sysctls(host["sysctls"])
        subprocess.run(["ip", "addr", "del", f"{host['node_ip']}/32", "dev", "lo"],
                       capture_output=True, check=False)
        subprocess.run(["ip", "link", "delete", POD_BRIDGE], capture_output=True, check=False)
        remove_cgroup_tree("kubepods")
        pod_logs = host.get("pod_logs", "")
        if CONTAINER_LOGS_DIR.is_dir() and pod_logs:
            for link in CONTAINER_LOGS_DIR.iterdir():
                with contextlib.suppress(OSError):
                    if link.is_symlink() and os.readlink(link).startswith(pod_logs):
                        link.unlink()
        if NETNS_DIR.is_dir():
            for ns in NETNS_DIR.glob("cni-*"):
                if ns.name not in host.get("netns_before", []):
                    subprocess.run(["ip", "netns", "delete", ns.name], capture_output=True,
                                   check=False)
        if CNI_RESULTS.is_dir():
            for result in CNI_RESULTS.glob(f"{CNI_NETWORK}-*"):
                result.unlink(missing_ok=True)
        for created in reversed(host.get("created", [])):
            path = Path(created)
            if path == KUBELET_HOST_DIR or (
                    path == SHIM_SOCKET_DIR.parent and not (path / "containerd.sock").exists()):
                # Ours alone: the device-plugin dir; the sockets of shims killed at stop.
                shutil.rmtree(path, ignore_errors=True)
                continue
            remove_empty_dirs(path)
        HOST_STATE.unlink(missing_ok=True)
        self._host = {}

    def _drain(self) -> None:
        """Delete this node's pods and wait (briefly) for the kubelet to stop them."""
        with contextlib.suppress(Exception):
            pods = json.loads(self.plane.kubectl(
                "get", "pods", "-A", f"--field-selector=spec.nodeName={self.name}", "-o", "json",
                timeout=20).stdout)["items"]
            for pod in pods:
                meta = pod["metadata"]
                self.plane.kubectl("delete", "pod", meta["name"], "-n", meta["namespace"],
                                   "--grace-period=1", "--wait=false", check=False, timeout=20)
            if pods:
                wait_until(lambda: not self.containerd or not self.containerd.running_tasks(), timeout=20,
                           interval=0.5,
                           what="pods on the node to stop")
