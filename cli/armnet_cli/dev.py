"""``armnet dev up``: the test bed's control plane, node, NATS, object store and Podman API for manual use.

Starts exactly what the pytest fixtures start (``armnet_testbed``, the distribution
``armnet-testbed`` in ``testbed/`` of a checkout, which ``scripts/setup.sh`` installs
into the development venv), prints the variables to export, and stops everything on
Ctrl-C. The test bed is in no wheel and no image on purpose: it is development
tooling, and it builds images and reads charts from the checkout it was installed from.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from pathlib import Path
from typing import Any


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="dev_action", metavar="ACTION", required=True)
    up = actions.add_parser("up", help="start kube-apiserver+etcd, a node (containerd + "
                                       "kubelet), NATS, an S3 store and the Podman API; Ctrl-C stops them")
    up.add_argument("--no-k8s", action="store_true",
                    help="do not start etcd + kube-apiserver (nor the node)")
    up.add_argument("--no-node", action="store_true",
                    help="do not start the node (containerd + kubelet; needs root, changes "
                         "host sysctls/cgroups until Ctrl-C, holds the host's node lock)")
    up.add_argument("--no-controllers", action="store_true",
                    help="with the node, do not start kube-controller-manager and kube-scheduler "
                         "(without them a Deployment or DaemonSet, e.g. the Helm chart's, makes no pods)")
    up.add_argument("--no-nats", action="store_true", help="do not start nats-server")
    up.add_argument("--no-podman", action="store_true", help="do not start the Podman API service")
    up.add_argument("--no-store", action="store_true",
                    help="do not start the S3-compatible object store (SeaweedFS) for job outputs")


#: The bucket `armnet dev up` makes for job outputs.
DEV_BUCKET = "armnet-outputs"
#: The bed's two tenants: a Kubernetes user each and, with the store, read keys to the outputs of the
#: namespace of the same name (docs/outputs.md, "Tenants' keys").
TENANTS = ("tenant-a", "tenant-b")


def _import_testbed() -> Any:
    try:
        import armnet_testbed
    except ImportError as error:
        raise SystemExit(
            f"armnet dev up needs the test bed (armnet-testbed), which is not installed here ({error}): "
            "it is development tooling of a source checkout; run scripts/setup.sh in the checkout and use "
            "its venv (~/.cache/armnet/venv/bin/armnet dev up)") from None
    return armnet_testbed


def run(args: argparse.Namespace) -> int:
    if args.dev_action != "up":  # argparse enforces the choice; kept for clarity
        return 2
    testbed = _import_testbed()
    stop = threading.Event()
    # Handlers, not KeyboardInterrupt: a shell may start us with SIGINT ignored.
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    with contextlib.ExitStack() as stack:
        try:
            lines = _start_all(testbed, args, stack)
        except testbed.TestbedSetupError as exc:
            print(f"armnet dev up: {exc}", file=sys.stderr)
            return 1
        print("\n# test bed is up; paste into your shell:")
        for line in lines:
            print(line)
        print("# Ctrl-C stops everything and removes the temporary state.", flush=True)
        stop.wait()
        print("\nstopping the test bed ...", file=sys.stderr, flush=True)
    return 0


def _start_all(testbed: Any, args: argparse.Namespace, stack: contextlib.ExitStack) -> list[str]:
    lines: list[str] = []
    if not args.no_k8s:
        plane = stack.enter_context(testbed.ControlPlane())
        lines.append(f"export KUBECONFIG={plane.kubeconfig}")
        lines.append(f"export PATH={Path(plane.kubectl_path).parent}:$PATH   # kubectl "
                     f"matching the apiserver")
        for name in TENANTS:
            user = plane.user(name)
            lines.append(f"# tenant {name}: KUBECONFIG={user.kubeconfig}")
        if not args.no_node:
            node = stack.enter_context(testbed.Node(plane=plane))
            lines.append(f"# node {node.name} is Ready: pods need spec.nodeName: {node.name}, "
                         f"imagePullPolicy: Never, dnsPolicy: Default")
            lines.append(f"# images on the node: {', '.join(node.images)}; more: "
                         f"ctr --address {node.socket} -n k8s.io images import <podman save archive>")
            lines.append(f"# kubelet log: {node.kubelet_log}")
            lines.append(f"# kubelet root dir (the chart's agent.kubeletRootDir): {node.kubelet_root_dir}")
            if not args.no_controllers:
                stack.enter_context(testbed.WorkloadControllers(plane=plane))
                lines.append("# kube-controller-manager and kube-scheduler are running: Deployments and "
                             "DaemonSets (the Helm chart's) make pods on the node")
    if not args.no_nats:
        nats = stack.enter_context(testbed.NatsServer())
        lines.append(f"export NATS_URL={nats.url}")
    if not args.no_store:
        store = stack.enter_context(testbed.SeaweedS3(readers={name: (DEV_BUCKET, name) for name in TENANTS}))
        bucket = store.create_bucket(DEV_BUCKET)
        agent_env = " ".join(f"{key}={value}" for key, value in store.agent_env(bucket).items())
        lines.append(f"# object store for job outputs (docs/outputs.md): start the agent with {agent_env}")
        lines.append(f"# read them back: AWS_ACCESS_KEY_ID={store.access_key} AWS_SECRET_ACCESS_KEY={store.secret_key} "
                     f"armnet artifacts JOB --endpoint {store.endpoint}")
        for reader in store.readers.values():
            keys = " ".join(f"{key}={value}" for key, value in reader.env().items())
            lines.append(f"# tenant {reader.name}: the outputs of namespace {reader.namespace} only: {keys} "
                         f"armnet artifacts JOB -n {reader.namespace}")
        lines.append(f"export ARMNET_ARTIFACTS_ENDPOINT={store.endpoint}")
    if not args.no_podman:
        podman = stack.enter_context(testbed.PodmanService())
        lines.append(f"export DOCKER_HOST={podman.base_url}")
    return lines
