"""``armnet dev up``: the test bed's control plane, node, NATS, object store and Podman API for manual use.

Starts exactly what the pytest fixtures start (the library lives in
``tests/testbed`` of a checkout), prints the variables to export, and stops
everything on Ctrl-C. It needs a source checkout: the test bed is not shipped in
the wheel on purpose (it is development tooling, not product code).
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
    up.add_argument("--repo", type=Path, default=None,
                    help="repository checkout holding tests/testbed (default: found from cwd)")


#: The bucket `armnet dev up` makes for job outputs.
DEV_BUCKET = "armnet-outputs"


def _find_checkout(start: Path) -> Path | None:
    for candidate in (start, *start.parents):
        if (candidate / "tests" / "testbed" / "__init__.py").is_file():
            return candidate
    here = Path(__file__).resolve()
    for candidate in here.parents:
        if (candidate / "tests" / "testbed" / "__init__.py").is_file():
            return candidate
    return None


def _import_testbed(repo: Path | None) -> Any:
    root = repo.resolve() if repo else _find_checkout(Path.cwd().resolve())
    if root is None or not (root / "tests" / "testbed" / "__init__.py").is_file():
        raise SystemExit("armnet dev up needs a source checkout of armnet (it uses tests/testbed): "
                         "run it from the repository root, or pass --repo PATH")
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    import tests.testbed as testbed

    return testbed


def run(args: argparse.Namespace) -> int:
    if args.dev_action != "up":  # argparse enforces the choice; kept for clarity
        return 2
    testbed = _import_testbed(args.repo)
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
        for name in ("tenant-a", "tenant-b"):
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
        store = stack.enter_context(testbed.SeaweedS3())
        bucket = store.create_bucket(DEV_BUCKET)
        agent_env = " ".join(f"{key}={value}" for key, value in store.agent_env(bucket).items())
        lines.append(f"# object store for job outputs (docs/outputs.md): start the agent with {agent_env}")
        lines.append(f"# read them back: AWS_ACCESS_KEY_ID={store.access_key} AWS_SECRET_ACCESS_KEY={store.secret_key} "
                     f"armnet artifacts JOB --endpoint {store.endpoint}")
        lines.append(f"export ARMNET_ARTIFACTS_ENDPOINT={store.endpoint}")
    if not args.no_podman:
        podman = stack.enter_context(testbed.PodmanService())
        lines.append(f"export DOCKER_HOST={podman.base_url}")
    return lines
