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
from pathlib import Path

from armnet_agent.launch.container import EngineUnavailable, connect_engine
from armnet_agent.node.agent import AgentSettings, NodeAgent
from armnet_agent.node.kube import AgentKube, make_client
from armnet_agent.node.metrics import AgentMetrics
from armnet_agent.node.publish import open_link, register_metrics

ENV = "ARMNET_AGENT_"


def _env(name: str, default: str | None = None) -> str | None:
    return os.environ.get(ENV + name, default)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--node-name", default=_env("NODE_NAME") or socket.gethostname(),
                        help="serve the Cells whose spec.nodeName is this (default: the hostname)")
    parser.add_argument("--kubeconfig", default=_env("KUBECONFIG"), help="default: in-cluster, else KUBECONFIG")
    parser.add_argument("--namespaces", default=_env("NAMESPACES", ""),
                        help="comma-separated namespaces whose RobotJobs to run (default: all)")
    parser.add_argument("--state-dir", type=Path,
                        default=Path(_env("STATE_DIR") or Path(tempfile.gettempdir()) / "armnet-agent"),
                        help="job sockets, calibration copies, caches and volumes (keep the path short)")
    parser.add_argument("--heartbeat-period", type=float, default=float(_env("HEARTBEAT_PERIOD", "5") or 5),
                        help="seconds between heartbeats (keep well under the operator's --heartbeat-timeout)")
    parser.add_argument("--pass-period", type=float, default=float(_env("PASS_PERIOD", "2") or 2),
                        help="a full pass runs at least this often; watch events trigger passes sooner")
    parser.add_argument("--engine-url", default=_env("ENGINE_URL"),
                        help="Docker API of the container engine (default: DOCKER_HOST, else Podman's socket)")
    parser.add_argument("--nats-url", default=_env("NATS_URL"), help="publish job output to NATS (default: off)")
    parser.add_argument("--metrics-port", type=int, default=int(_env("METRICS_PORT", "9090") or 9090),
                        help="/metrics port (0: off)")
    parser.add_argument("--metrics-address", default=_env("METRICS_ADDRESS", "0.0.0.0"))
    parser.add_argument("--dev-mount", action="append", default=[],
                        help="development only: mount this host path read-only at the same path in job containers")
    parser.add_argument("--dev-env", action="append", default=[],
                        help="development only: NAME=VALUE added to every job container's env (e.g. PATH)")
    parser.add_argument("--verbose", action="store_true")


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s armnet agent %(levelname)s %(name)s: %(message)s")
    logging.getLogger("armnet_agent.node").setLevel(logging.INFO)
    try:
        engine = connect_engine(args.engine_url)
    except EngineUnavailable as exc:
        logging.error("%s", exc)
        return 1
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
        dev_mounts=tuple(args.dev_mount),
        dev_env=dev_env,
    )
    metrics = AgentMetrics()
    metrics.serve(args.metrics_port, args.metrics_address)
    link = open_link(args.nats_url, state_dir / "spool")
    register_metrics(link, metrics.registry)
    kube = AgentKube(make_client(args.kubeconfig), settings.namespaces)
    stop = threading.Event()

    def _stop(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    agent = NodeAgent(settings, kube, engine, metrics, link)
    try:
        agent.run(stop)
    finally:
        link.stop()
    return 0
