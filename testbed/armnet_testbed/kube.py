"""A real Kubernetes control plane for tests: etcd + kube-apiserver on loopback.

Owns: the binaries' location (built by scripts/setup.d/30-k8s.sh), the PKI, the
static token file, kubeconfigs per identity, readiness, and applying ``crds/``.
It never runs a controller-manager or scheduler, so namespaces never finish
deleting, pods without a node stay Pending and there is no ``default``
ServiceAccount (see docs/reference/testbed-host.md, "A control plane without
controllers"). Fresh etcd per start.

The plane is always node-capable (``testbed/armnet_testbed/node.py`` adds a real kubelet on
demand): the Node authorizer and the NodeRestriction admission plugin only judge
requests from ``system:nodes`` users, and the kubelet client certificate is only
used when the apiserver calls a kubelet (logs, exec), so none of it changes what
other tests see, and node tests share this plane instead of starting a second one.
"""

from __future__ import annotations

import base64
import os
import re
import shutil
import ssl
import subprocess
import tempfile
import time
import urllib.request
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from armnet_testbed.errors import TestbedSetupError
from armnet_testbed.pki import Pki, create_pki
from armnet_testbed.procs import ManagedProcess, free_port, progress, require_tool, wait_until

REPO_ROOT = Path(__file__).resolve().parents[2]
FIXTURES = Path(__file__).resolve().parent / "fixtures"
K8S_CACHE = Path(os.environ.get("ARMNET_K8S_DIR", Path.home() / ".cache/armnet/k8s"))

ADMIN_USER = "armnet-admin"
# The apiserver's identity towards kubelets (logs, exec, port-forward); a node
# binds it to system:kubelet-api-admin.
KUBELET_CLIENT_USER = "armnet-apiserver-kubelet-client"
TENANT_GROUP = "armnet:tenants"
# Identities with static tokens (the token file is read once at apiserver start).
# Any other identity gets a client certificate from `user()`.
STATIC_USERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (ADMIN_USER, ("system:masters",)),
    ("tenant-a", (TENANT_GROUP,)),
    ("tenant-b", (TENANT_GROUP,)),
    ("armnet-operator", ("armnet:operators",)),
    ("armnet-agent-1", ("armnet:agents",)),
)


def k8s_bin_dir() -> Path:
    """``~/.cache/armnet/k8s/v<version>/bin`` of the version setup built last."""
    override = os.environ.get("ARMNET_K8S_BIN")
    if override:
        return Path(override)
    current = K8S_CACHE / "current"
    if not current.is_file():
        raise TestbedSetupError(f"no Kubernetes binaries built yet ({current} is missing)")
    return K8S_CACHE / f"v{current.read_text().strip()}" / "bin"


@dataclass(frozen=True)
class KubeUser:
    """One authenticated identity: a kubeconfig, and its bearer token if it has one."""

    name: str
    groups: tuple[str, ...]
    kubeconfig: Path
    token: str | None = None
    client_cert: Path | None = None
    client_key: Path | None = None


@dataclass
class ControlPlane:
    """etcd + kube-apiserver with TLS, RBAC, a service-account issuer and static tokens."""

    workdir: Path | None = None
    crd_paths: list[Path] = field(default_factory=list)
    apply_repo_crds: bool = True
    startup_timeout: float = 120.0

    url: str = ""
    kubectl_path: str = ""
    admin: KubeUser | None = None
    pki: Pki | None = None
    _procs: list[ManagedProcess] = field(default_factory=list)
    _tokens: dict[str, str] = field(default_factory=dict)
    _users: dict[tuple[str, tuple[str, ...]], KubeUser] = field(default_factory=dict)
    _owns_workdir: bool = False
    _core_api: Any = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> ControlPlane:
        started = time.monotonic()
        bins = k8s_bin_dir()
        etcd = require_tool("etcd", bins / "etcd")
        apiserver = require_tool("kube-apiserver", bins / "kube-apiserver")
        self.kubectl_path = require_tool("kubectl", bins / "kubectl")
        if self.workdir is None:
            self.workdir = Path(tempfile.mkdtemp(prefix="armnet-k8s-"))
            self._owns_workdir = True
        try:
            self._start(etcd, apiserver)
        except BaseException:
            self.stop()
            raise
        progress(f"control plane ready at {self.url} in {time.monotonic() - started:.1f} s")
        return self

    def _start(self, etcd: str, apiserver: str) -> None:
        assert self.workdir is not None
        w = self.workdir
        self.pki = create_pki(w / "pki")
        token_file = w / "tokens.csv"
        lines = []
        for name, groups in STATIC_USERS:
            token = uuid.uuid4().hex
            self._tokens[name] = token
            lines.append(f'{token},{name},uid-{name},"{",".join(groups)}"')
        token_file.write_text("\n".join(lines) + "\n")

        kubelet_client_cert, kubelet_client_key = self.pki.client_cert(KUBELET_CLIENT_USER, ())
        client_port, peer_port, api_port = free_port(), free_port(), free_port()
        progress(f"starting etcd on 127.0.0.1:{client_port}")
        etcd_proc = ManagedProcess("etcd", [
            etcd, "--name", "armnet", "--data-dir", str(w / "etcd"),
            "--listen-client-urls", f"http://127.0.0.1:{client_port}",
            "--advertise-client-urls", f"http://127.0.0.1:{client_port}",
            "--listen-peer-urls", f"http://127.0.0.1:{peer_port}",
            "--initial-advertise-peer-urls", f"http://127.0.0.1:{peer_port}",
            "--initial-cluster", f"armnet=http://127.0.0.1:{peer_port}",
            "--unsafe-no-fsync", "--log-level", "warn",
        ], w / "etcd.log")
        self._procs.append(etcd_proc)
        wait_until(lambda: _http_ok(f"http://127.0.0.1:{client_port}/health"), timeout=30,
                   what="etcd /health", alive=etcd_proc.ensure_running)

        self.url = f"https://127.0.0.1:{api_port}"
        progress(f"starting kube-apiserver on {self.url}")
        p = self.pki
        api_proc = ManagedProcess("kube-apiserver", [
            apiserver,
            f"--etcd-servers=http://127.0.0.1:{client_port}",
            "--bind-address=127.0.0.1", "--advertise-address=127.0.0.1",
            f"--secure-port={api_port}", f"--cert-dir={w / 'apiserver'}",
            f"--tls-cert-file={p.server_cert}", f"--tls-private-key-file={p.server_key}",
            f"--client-ca-file={p.ca_cert}", f"--token-auth-file={token_file}",
            f"--service-account-issuer={self.url}",
            f"--service-account-key-file={p.sa_pub}",
            f"--service-account-signing-key-file={p.sa_key}",
            "--service-cluster-ip-range=10.0.0.0/24",
            "--authorization-mode=Node,RBAC", "--allow-privileged=true",
            # No controller-manager creates `default` ServiceAccounts here.
            "--disable-admission-plugins=ServiceAccount",
            "--enable-admission-plugins=NodeRestriction",
            # For a test-bed node (node.py): the apiserver calls kubelets by their
            # InternalIP (the node name does not resolve) with a client cert, and
            # checks the kubelet's serving cert against the test-bed CA.
            f"--kubelet-client-certificate={kubelet_client_cert}",
            f"--kubelet-client-key={kubelet_client_key}",
            f"--kubelet-certificate-authority={p.ca_cert}",
            "--kubelet-preferred-address-types=InternalIP",
            "--profiling=false",
            # Idle CPU, measured on an idle test-bed plane: 0.088 of a core with the defaults,
            # 0.029 without these two (the suite runs three planes beside its tests on two
            # cores). Priority and fairness re-evaluates its flow schemas and levels on timers;
            # the endpoint reconciler rewrites the `kubernetes` Service's lease every 10 s.
            # Neither is under test: nothing here reaches the apiserver through that Service
            # (a test-bed pod gets KUBERNETES_SERVICE_HOST/PORT pointing at loopback).
            "--enable-priority-and-fairness=false",
            "--endpoint-reconciler-type=none",
        ], w / "kube-apiserver.log")
        self._procs.append(api_proc)

        self.admin = self._write_user(ADMIN_USER, ("system:masters",), token=self._tokens[ADMIN_USER])
        ca = ssl.create_default_context(cafile=str(p.ca_cert))
        wait_until(lambda: _http_ok(f"{self.url}/readyz", ca, self._tokens[ADMIN_USER]),
                   timeout=self.startup_timeout, interval=0.5, what="kube-apiserver /readyz",
                   alive=api_proc.ensure_running)
        self._apply_crds()

    def stop(self) -> None:
        if self._core_api is not None:
            self._core_api.api_client.close()
            self._core_api = None
        for proc in reversed(self._procs):
            proc.stop()
        self._procs.clear()
        if self._owns_workdir and self.workdir is not None:
            shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self) -> ControlPlane:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ identities
    @property
    def kubeconfig(self) -> Path:
        assert self.admin is not None, "control plane not started"
        return self.admin.kubeconfig

    @property
    def admin_token(self) -> str:
        return self._tokens[ADMIN_USER]

    def user(self, name: str, groups: tuple[str, ...] | list[str] = (TENANT_GROUP,)) -> KubeUser:
        """A tenant identity: a static token if it is one of STATIC_USERS, else a client cert.

        Both are real authentication; RBAC sees user ``name`` in ``groups``.
        """
        key = (name, tuple(groups))
        if key in self._users:
            return self._users[key]
        static = dict(STATIC_USERS)
        if name in static and tuple(static[name]) == key[1]:
            user = self._write_user(name, key[1], token=self._tokens[name])
        else:
            assert self.pki is not None
            cert, client_key = self.pki.client_cert(name, key[1])
            user = self._write_user(name, key[1], cert=cert, key=client_key)
        self._users[key] = user
        return user

    def _write_user(self, name: str, groups: tuple[str, ...], *, token: str | None = None,
                    cert: Path | None = None, key: Path | None = None) -> KubeUser:
        assert self.workdir is not None and self.pki is not None
        credentials: dict[str, Any] = {"token": token} if token else {
            "client-certificate": str(cert), "client-key": str(key)}
        config = {
            "apiVersion": "v1", "kind": "Config", "current-context": "armnet",
            "clusters": [{"name": "armnet", "cluster": {
                "server": self.url,
                "certificate-authority-data": base64.b64encode(
                    self.pki.ca_cert.read_bytes()).decode()}}],
            "users": [{"name": name, "user": credentials}],
            "contexts": [{"name": "armnet", "context": {"cluster": "armnet", "user": name}}],
        }
        path = self.workdir / f"kubeconfig-{name.replace(':', '_')}"
        path.write_text(yaml.safe_dump(config))
        path.chmod(0o600)
        return KubeUser(name=name, groups=groups, kubeconfig=path, token=token,
                        client_cert=cert, client_key=key)

    # ------------------------------------------------------------------ clients
    def kubectl(self, *args: str, user: KubeUser | None = None, input: str | None = None,
                check: bool = True, timeout: float = 60) -> subprocess.CompletedProcess[str]:
        """Run the built kubectl as ``user`` (admin by default); raises on failure if ``check``."""
        who = user or self.admin
        assert who is not None, "control plane not started"
        argv = [self.kubectl_path, f"--kubeconfig={who.kubeconfig}", *args]
        result = subprocess.run(argv, input=input, capture_output=True, text=True,
                                timeout=timeout, check=False)
        if check and result.returncode != 0:
            error = subprocess.CalledProcessError(result.returncode, argv, result.stdout, result.stderr)
            error.add_note(f"kubectl said: {result.stderr.strip() or result.stdout.strip() or '(nothing)'}")
            raise error
        return result

    def api_client(self, user: KubeUser | None = None) -> Any:
        """A ``kubernetes.client.ApiClient`` for ``user`` (admin by default)."""
        from kubernetes import config  # imported lazily: only some tests need it

        who = user or self.admin
        assert who is not None
        return config.new_client_from_config(config_file=str(who.kubeconfig))

    def env(self) -> dict[str, str]:
        """Environment for a child process that should talk to this cluster as admin."""
        return {**os.environ, "KUBECONFIG": str(self.kubeconfig)}

    # ------------------------------------------------------------------ namespaces and CRDs
    def create_namespace(self, prefix: str = "t") -> str:
        """A new namespace ``<prefix>-<8 hex>`` (prefix sanitized to a DNS label)."""
        label = re.sub(r"[^a-z0-9-]+", "-", prefix.lower())[:40].strip("-") or "t"
        name = f"{label}-{uuid.uuid4().hex[:8]}"
        self._core().create_namespace({"metadata": {"name": name}})
        return name

    def delete_namespace(self, name: str) -> None:
        """Ask for the namespace's deletion; not waited for, and a failure only printed (teardown).

        Without a controller-manager a namespace stays Terminating forever. Through the
        API client, not kubectl: the suite makes and deletes hundreds, and each kubectl run
        costs ~80 ms of CPU (about a CPU-minute over a warm run).
        """
        try:
            self._core().delete_namespace(name)
        except Exception as exc:  # noqa: BLE001 - gone already, or a plane stopping: nothing to clean
            progress(f"deleting namespace {name}: {str(exc).splitlines()[0][:200]}")

    def _core(self) -> Any:
        """The admin's CoreV1Api, made once (its client holds a connection pool)."""
        if self._core_api is None:
            from kubernetes import client

            self._core_api = client.CoreV1Api(self.api_client())
        return self._core_api

    def crd_files(self) -> list[Path]:
        files = sorted(FIXTURES.glob("*crd*.yaml")) + list(self.crd_paths)
        if self.apply_repo_crds:
            files += sorted((REPO_ROOT / "crds").glob("*.yaml"))
        return files

    def _apply_crds(self) -> None:
        files = self.crd_files()
        if not files:
            return
        names = []
        for f in files:
            for doc in yaml.safe_load_all(f.read_text()):
                if isinstance(doc, dict) and doc.get("kind") == "CustomResourceDefinition":
                    names.append(f"crd/{doc['metadata']['name']}")
        progress(f"applying {len(files)} CRD file(s): {', '.join(f.name for f in files)}")
        self.kubectl("apply", "--server-side", *[a for f in files for a in ("-f", str(f))])
        if names:
            self.wait_established(*names)

    def wait_established(self, *names: str, timeout: float = 180) -> None:
        """Wait until every ``crd/NAME`` in ``names`` is served (condition Established).

        Polls rather than ``kubectl wait``: that fails at once on a CRD not created yet
        (a ``replace --force`` in flight) and gives no sign of where it stood at its deadline.
        """
        last: dict[str, str] = {}

        def established() -> bool:
            for name in names:
                got = self.kubectl("get", name, "-o", 'jsonpath={.status.conditions[?(@.type=="Established")].status}',
                                   check=False)
                last[name] = got.stdout.strip() or got.stderr.strip() or "(no conditions yet)"
            return all(state == "True" for state in last.values())

        try:
            wait_until(established, timeout=timeout, interval=0.5, what=f"{', '.join(names)} established")
        except TimeoutError as exc:
            raise TimeoutError(f"{exc}; last seen: {last}") from None


def _http_ok(url: str, context: ssl.SSLContext | None = None, token: str | None = None) -> bool:
    request = urllib.request.Request(url)
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=2, context=context) as response:
            return bool(response.status == 200)
    except (OSError, ValueError):
        return False
