"""kube-controller-manager and kube-scheduler for the tests that need workload controllers.

The rest of the test bed runs without them (pods are created with ``spec.nodeName``);
the chart's real install does not: its operator Deployment and agent DaemonSet become
pods only through the deployment, replicaset and daemonset controllers and the
scheduler. Only the controllers that needs are on, plus the garbage collector (an
uninstall removes the pods), the root-CA publisher (the chart's projected token
volume mounts its ``kube-root-ca.crt`` ConfigMap) and the node lifecycle controller
(it lifts the ``node.kubernetes.io/not-ready`` taint a kubelet registers with, which
would keep the scheduler from placing the operator). Both run with the admin
kubeconfig, without leader election and without a serving port, and stop with the
context manager. Binaries: scripts/setup.d/30-k8s.sh.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from armnet_testbed.kube import ControlPlane, k8s_bin_dir
from armnet_testbed.procs import ManagedProcess, progress, require_tool

CONTROLLERS = ("deployment-controller", "replicaset-controller", "daemonset-controller",
               "garbage-collector-controller", "root-ca-certificate-publisher-controller",
               "node-lifecycle-controller")


@dataclass
class WorkloadControllers:
    """``kube-controller-manager`` (the controllers above) + ``kube-scheduler`` on ``plane``."""

    plane: ControlPlane
    #: The controller-manager's controllers (a test of the garbage collector alone runs only that one).
    controllers: tuple[str, ...] = CONTROLLERS
    scheduler: bool = True
    #: More controller-manager flags (e.g. ``--concurrent-gc-syncs=1``).
    extra_args: tuple[str, ...] = ()
    _procs: list[ManagedProcess] = field(default_factory=list)
    _workdir: Path | None = None

    def start(self) -> WorkloadControllers:
        started = time.monotonic()
        bins = k8s_bin_dir()
        manager = require_tool("kube-controller-manager", bins / "kube-controller-manager")
        scheduler = require_tool("kube-scheduler", bins / "kube-scheduler") if self.scheduler else None
        assert self.plane.pki is not None
        self._workdir = Path(tempfile.mkdtemp(prefix="armnet-controllers-"))
        kubeconfig = str(self.plane.kubeconfig)
        try:
            self._procs.append(ManagedProcess("kube-controller-manager", [
                manager, f"--kubeconfig={kubeconfig}", "--leader-elect=false",
                f"--controllers={','.join(self.controllers)}", "--secure-port=0",
                f"--root-ca-file={self.plane.pki.ca_cert}", "--concurrent-deployment-syncs=2",
                "--concurrent-replicaset-syncs=2", "--concurrent-daemonset-syncs=2", "--v=1",
                *self.extra_args,
            ], self._workdir / "kube-controller-manager.log"))
            if scheduler is not None:
                self._procs.append(ManagedProcess("kube-scheduler", [
                    scheduler, f"--kubeconfig={kubeconfig}", "--leader-elect=false",
                    "--secure-port=0", "--v=1",
                ], self._workdir / "kube-scheduler.log"))
            time.sleep(1)
            for proc in self._procs:
                proc.ensure_running()
        except BaseException:
            self.stop()
            raise
        progress(f"controller manager + scheduler started in {time.monotonic() - started:.1f} s "
                 f"(logs in {self._workdir})")
        return self

    def ensure_running(self) -> None:
        for proc in self._procs:
            proc.ensure_running()

    def log_tail(self, lines: int = 20) -> str:
        return "\n".join(f"--- {p.name}\n{p.log_tail(lines)}" for p in self._procs)

    def stop(self) -> None:
        for proc in reversed(self._procs):
            proc.stop()
        self._procs.clear()
        if self._workdir is not None:
            shutil.rmtree(self._workdir, ignore_errors=True)
            self._workdir = None

    def __enter__(self) -> WorkloadControllers:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
