"""``armnet agent``: the node agent of one robot host (see docs/agent.md).

Flags win over ``ARMNET_AGENT_*`` environment variables. SIGTERM and Ctrl-C
stop the loop and stop running jobs the graceful way (their containers are
killed at the end of their grace window); SIGKILL leaves them running, and the
next agent re-adopts them.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import socket
import tempfile
import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from armnet_connector.warm_imports import import_before_threads
from armnet_core.api import ARTIFACTS_BUCKET_ENV
from armnet_core.cell_completion import DEFAULT_COMPLETION_DIRS
from armnet_core.nats_url import nats_url_from
from armnet_core.object_store import StoreSettingsError
from armnet_launch.container import EngineUnavailable, connect_engine
from armnet_launch.pod_spec import CONNECTOR_USER

from armnet_node.agent import AgentSettings, NodeAgent
from armnet_node.artifacts import ObjectStore, StoreConfig
from armnet_node.deviceplugin.server import DEVICE_PLUGIN_DIR, DevicePlugins
from armnet_node.kube import AgentKube, make_client
from armnet_node.launchers import ContainerLauncher, JobLauncher, PodLauncher, PodSettings
from armnet_node.metrics import AgentMetrics
from armnet_node.publish import open_link, register_metrics
from armnet_node.telemetry import MAX_FRAME_FPS, MAX_SERVO_HZ, TelemetrySettings

ENV = "ARMNET_AGENT_"


def _env(name: str, default: str | None = None) -> str | None:
    return os.environ.get(ENV + name, default)


def _rate(bound: float) -> Callable[[str], float]:
    """An argparse type: a rate per second in 0..``bound`` (argparse turns the error into a usage error)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not 0 <= value <= bound:
            raise argparse.ArgumentTypeError(f"{value:g} is outside 0..{bound:g} per second (0 turns it off)")
        return value

    return parse


def _uid(text: str) -> int:
    """An argparse type: a numeric uid (Kubernetes' runAsUser takes no names)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a numeric uid") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} is not a uid")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--node-name", default=_env("NODE_NAME") or socket.gethostname(),
                        help="serve the Cells whose spec.nodeName is this (default: the hostname)")
    parser.add_argument("--kubeconfig", default=_env("KUBECONFIG"), help="default: in-cluster, else KUBECONFIG")
    parser.add_argument("--namespaces", default=_env("NAMESPACES", ""),
                        help="comma-separated namespaces whose RobotJobs to run (default: all)")
    parser.add_argument("--state-dir", type=Path,
                        default=Path(_env("STATE_DIR") or Path(tempfile.gettempdir()) / "armnet-agent"),
                        help="job sockets, calibration copies, caches and volumes (keep the path short)")
    parser.add_argument("--config-namespace", default=_env("CONFIG_NAMESPACE") or os.environ.get("POD_NAMESPACE"),
                        help="where the ConfigMaps a Cell names live (a classifier's model): the platform's "
                             "namespace (default: the agent pod's own, POD_NAMESPACE)")
    parser.add_argument("--heartbeat-period", type=float, default=float(_env("HEARTBEAT_PERIOD", "5") or 5),
                        help="seconds between heartbeats (keep well under the operator's --heartbeat-timeout)")
    parser.add_argument("--pass-period", type=float, default=float(_env("PASS_PERIOD", "2") or 2),
                        help="a full pass runs at least this often; watch events trigger passes sooner")
    parser.add_argument("--engine-url", default=_env("ENGINE_URL"),
                        help="Docker API of the container engine (default: DOCKER_HOST, else Podman's socket)")
    parser.add_argument("--nats-url", default=nats_url_from(None, os.environ, ENV + "NATS_URL"),
                        help="NATS: job output, live logs, and the cell operator's inputs (Confirm reset, "
                             "Success/Fail) and teleop (default: $ARMNET_AGENT_NATS_URL, else $NATS_URL, else off; "
                             "without it each of this node's Cells shows StreamsConnected=False)")
    parser.add_argument("--telemetry-servo-hz", type=_rate(MAX_SERVO_HZ), default=_env("TELEMETRY_SERVO_HZ", "4"),
                        help="servo telemetry reads per second published for the cell operator's page "
                             f"(0: off, at most {MAX_SERVO_HZ:g}; needs --nats-url)")
    parser.add_argument("--telemetry-frame-fps", type=_rate(MAX_FRAME_FPS), default=_env("TELEMETRY_FRAME_FPS", "2"),
                        help=f"camera frames per second published for the cell operator's page (0: off, at most "
                             f"{MAX_FRAME_FPS:g})")
    parser.add_argument("--metrics-port", type=int, default=int(_env("METRICS_PORT", "9090") or 9090),
                        help="/metrics port (0: off)")
    parser.add_argument("--metrics-address", default=_env("METRICS_ADDRESS", "0.0.0.0"))
    parser.add_argument("--dev-mount", action="append", default=[],
                        help="development only: mount this host path read-only at the same path in job containers")
    parser.add_argument("--completion-files-dir", action="append", default=None, metavar="DIR",
                        help="a host directory a Cell's completion monitor may read files from (a classifier's "
                             "model, a judge's token file); repeat for several. Default: "
                             f"{os.pathsep.join(DEFAULT_COMPLETION_DIRS)} (or ARMNET_AGENT_COMPLETION_FILES_DIRS, "
                             "separated by ':'); a Cell naming a file elsewhere is not bound (docs/connector.md)")
    parser.add_argument("--dev-env", action="append", default=[],
                        help="development only: NAME=VALUE added to every job container's env (e.g. PATH)")
    parser.add_argument("--launcher", choices=("container", "pod"), default=_env("LAUNCHER", "container"),
                        help="run jobs as containers through the Docker API (connector in the agent) or as pods "
                             "on this Kubernetes node (connector as the pod's native sidecar); see docs/agent.md")
    parser.add_argument("--connector-image", default=_env("CONNECTOR_IMAGE", "armnet/connector:latest"),
                        help="pod launcher: the connector sidecar's image")
    parser.add_argument("--connector-command", default=_env("CONNECTOR_COMMAND"),
                        help="pod launcher: the sidecar's command, space-separated "
                             "(default: python3 -m armnet_launch.sidecar)")
    parser.add_argument("--connector-user", type=_uid, default=_env("CONNECTOR_USER", str(CONNECTOR_USER)),
                        help=f"pod launcher: the connector sidecar's uid, set in the pod whatever the image's USER "
                             f"(default {CONNECTOR_USER}, the agent image's user, in the device groups); "
                             "0 runs it as root: development stand-in images only")
    parser.add_argument("--pod-simulator", choices=("agent", "sidecar"), default=_env("POD_SIMULATOR", "agent"),
                        help="pod launcher, simulated cells: run the simulator in the agent and hand its ptys to "
                             "the connector as devices, or in the job pod's sidecar (needed when the agent itself "
                             "runs in a pod: its ptys are its own container's)")
    parser.add_argument("--image-pull-policy", default=_env("IMAGE_PULL_POLICY", "IfNotPresent"),
                        choices=("Always", "IfNotPresent", "Never"), help="pod launcher: for both containers")
    parser.add_argument("--device-plugin", action=argparse.BooleanOptionalAction,
                        default=(_env("DEVICE_PLUGIN", "true") or "true").lower() not in ("0", "false", "no"),
                        help="pod launcher: serve the kubelet device-plugin API (one armnet.io/cell-<cell> resource "
                             "per cell) and have the connector request it; --no-device-plugin mounts the devices "
                             "as hostPath volumes instead, for kubelets without device plugins (docs/agent.md)")
    parser.add_argument("--device-plugin-dir", type=Path, default=Path(_env("DEVICE_PLUGIN_DIR") or DEVICE_PLUGIN_DIR),
                        help="the kubelet's device-plugin directory (its kubelet.sock; default: the kubelet's own)")
    parser.add_argument("--kubelet-root-dir", type=Path, default=Path(_env("KUBELET_ROOT_DIR") or "/var/lib/kubelet"),
                        help="pod launcher: the kubelet's --root-dir as this agent sees it; a job pod's connector "
                             "serves its telemetry and rollout events under <dir>/pods/<pod uid>/volumes/ "
                             "(in the DaemonSet: mounted read-only with HostToContainer propagation)")
    parser.add_argument("--verbose", action="store_true")


def completion_dirs(flags: list[str] | None, env_value: str | None) -> tuple[str, ...]:
    """The completion directories: the flags, else the env var's ':'-separated list (empty: none), else the
    defaults."""
    if flags:
        return tuple(flags)
    if env_value is not None:  # set but empty (the chart's hostPaths: []): no directory at all
        return tuple(d for d in env_value.split(os.pathsep) if d)
    return DEFAULT_COMPLETION_DIRS


def run(args: argparse.Namespace) -> int:
    import_before_threads()  # before any worker, connector or metrics thread (warm_imports.py)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s armnet agent %(levelname)s %(name)s: %(message)s")
    logging.getLogger("armnet_node").setLevel(logging.INFO)
    dev_env = {}
    for item in args.dev_env:
        key, sep, value = item.partition("=")
        if not sep:
            logging.error("--dev-env %r: use NAME=VALUE", item)
            return 2
        dev_env[key] = value
    state_dir = args.state_dir.resolve()
    state_dir.mkdir(parents=True, exist_ok=True)
    settings = AgentSettings(
        node_name=args.node_name,
        state_dir=state_dir,
        namespaces=tuple(n for n in args.namespaces.split(",") if n),
        heartbeat_period=args.heartbeat_period,
        pass_period=args.pass_period,
        telemetry=TelemetrySettings(args.telemetry_servo_hz, args.telemetry_frame_fps),
        dev_mounts=tuple(args.dev_mount),
        dev_env=dev_env,
        completion_dirs=completion_dirs(args.completion_files_dir, _env("COMPLETION_FILES_DIRS")),
        config_namespace=args.config_namespace or None,
    )
    try:
        store_config = StoreConfig.from_env()
    except StoreSettingsError as exc:
        logging.error("%s", exc)
        return 2
    if store_config is None:
        logging.warning("no object store for job outputs (%s is not set): what a job writes to its output "
                        "directory is removed when it ends (docs/outputs.md)", ARTIFACTS_BUCKET_ENV)
    metrics = AgentMetrics()
    metrics.serve(args.metrics_port, args.metrics_address)
    link = open_link(args.nats_url, state_dir / "spool")
    register_metrics(link, metrics.registry)
    api = make_client(args.kubeconfig)
    kube = AgentKube(api, settings.namespaces)
    launcher: JobLauncher
    device_plugins: DevicePlugins | None = None
    if args.launcher == "pod":
        from kubernetes import client

        pod_settings = PodSettings(
            node_name=settings.node_name,
            connector_image=args.connector_image,
            image_pull_policy=args.image_pull_policy,
            dev_mounts=settings.dev_mounts,
            dev_env=dev_env,
            device_plugin=args.device_plugin,
            simulator_in_pod=args.pod_simulator == "sidecar",
            kubelet_root=args.kubelet_root_dir,
            connector_user=args.connector_user,
        )
        if args.connector_user == 0:
            logging.warning("--connector-user 0: job pods' connectors run as root (development only)")
        if args.device_plugin:
            device_plugins = DevicePlugins(metrics, args.device_plugin_dir).start()
        if args.connector_command:
            pod_settings = replace(pod_settings, connector_command=tuple(args.connector_command.split()))
        launcher = PodLauncher(client.CoreV1Api(api), pod_settings, metrics, settings.namespaces)
    else:
        try:
            engine = connect_engine(args.engine_url)
        except EngineUnavailable as exc:
            logging.error("%s", exc)
            return 1
        launcher = ContainerLauncher(engine, metrics)
    stop = threading.Event()

    def _stop(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    store = ObjectStore(store_config) if store_config is not None else None
    agent = NodeAgent(settings, kube, launcher, metrics, link, device_plugins, store)
    try:
        agent.run(stop)
    finally:
        if device_plugins is not None:
            device_plugins.stop()
        link.stop()
    return 0
