"""``armnet fms``: serve the cell operator's page.

Flags fall back to ``ARMNET_FMS_*`` environment variables (the Helm chart sets
those from its values and Secret).
"""

from __future__ import annotations

import argparse
import logging
import os
import secrets
import sys
import time
from pathlib import Path

from armnet_core.nats_url import nats_url_from

from .auth import AuthConfigError, AuthSettings, parse_tokens

DEFAULT_NATS_URL = "nats://127.0.0.1:4222"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    env = os.environ.get
    parser.add_argument("--host", default=env("ARMNET_FMS_HOST", "0.0.0.0"), help="address to listen on")
    parser.add_argument("--port", type=int, default=int(env("ARMNET_FMS_PORT", "8080")))
    parser.add_argument("--kubeconfig", default=None, help="as kubectl (default: $KUBECONFIG, in-cluster)")
    parser.add_argument("--context", default=None)
    parser.add_argument("--nats-url", default=nats_url_from(None, os.environ, "ARMNET_FMS_NATS_URL") or DEFAULT_NATS_URL,
                        help="the agents' NATS (default: $ARMNET_FMS_NATS_URL, else $NATS_URL, else "
                             f"{DEFAULT_NATS_URL})")
    parser.add_argument("--operators-file", default=env("ARMNET_FMS_OPERATORS_FILE", ""),
                        help="'<operator>:<token>' lines (mount the auth Secret here)")
    parser.add_argument("--session-key-file", default=env("ARMNET_FMS_SESSION_KEY_FILE", ""),
                        help="key signing sessions and CSRF tokens (default: random per process; "
                             "replicas must share one)")
    parser.add_argument("--trusted-header", default=env("ARMNET_FMS_TRUSTED_HEADER", ""),
                        help="the auth proxy's user header, e.g. X-Forwarded-User; only when nothing but the "
                             "proxy can reach this port (docs/fms.md)")
    parser.add_argument("--site", default=env("ARMNET_FMS_SITE", ""), help="show only cells with this armnet.io/site label")
    parser.add_argument("--poll-interval", type=float, default=float(env("ARMNET_FMS_POLL_INTERVAL", "1.0")))
    parser.add_argument("--insecure-cookies", action="store_true",
                        help="session cookie without Secure (plain-HTTP development only)")


def load_auth(args: argparse.Namespace) -> AuthSettings:
    tokens = parse_tokens(Path(args.operators_file).read_text(encoding="utf-8")) if args.operators_file else {}
    if not tokens and not args.trusted_header:
        raise AuthConfigError("no way to log in: pass --operators-file (a Secret with '<operator>:<token>' lines) "
                              "and/or --trusted-header behind an auth proxy")
    key = Path(args.session_key_file).read_bytes().strip() if args.session_key_file else secrets.token_bytes(32)
    if len(key) < 16:
        raise AuthConfigError("the session key must be at least 16 bytes")
    return AuthSettings(secret_key=key, tokens=tokens, trusted_header=args.trusted_header)


def run(args: argparse.Namespace) -> int:
    import uvicorn
    from armnet_client.errors import ClientError
    from armnet_client.kube import ClusterTarget, connect
    from armnet_core.object_store import StoreConfig, StoreSettingsError

    from .app import build_app
    from .bus import Bus
    from .cell_video import CellVideos
    from .kube import KubeGateway
    from .state import FleetState
    from .telemetry import TelemetryStore

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        settings = load_auth(args)
        connection = connect(ClusterTarget(kubeconfig=args.kubeconfig, context=args.context))
    except (AuthConfigError, OSError, ClientError) as error:
        print(f"armnet fms: {error}", file=sys.stderr)
        return 2
    gateway = KubeGateway(connection.api_client)
    state = FleetState(gateway, poll_s=args.poll_interval)
    try:
        store = StoreConfig.from_env()
    except StoreSettingsError as error:
        print(f"armnet fms: {error}", file=sys.stderr)
        return 2
    videos = CellVideos(store, gateway.list_jobs) if store is not None else None
    telemetry = TelemetryStore(known_cells=state.cell_names)
    bus = Bus(args.nats_url, on_telemetry=lambda subject, data: telemetry.accept(subject, data, time.time()),
              on_dropped=telemetry.count_dropped)
    app = build_app(state, bus, settings, site=args.site, secure_cookies=not args.insecure_cookies,
                    telemetry=telemetry, videos=videos)
    uvicorn.run(app, host=args.host, port=args.port, log_level="info", access_log=False)
    return 0
