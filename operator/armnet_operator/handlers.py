"""The kopf edge: watch RobotJobs and Cells into the cache, run the controller.

Thin on purpose. Handlers only parse and store; all decisions happen in the
reconcile pass. Each call of ``build_registry`` makes an independent operator
(its own registry, cache and metrics), so tests can run two replicas in one
process. No ``on.field`` chains, no kopf-managed finalizers or annotations.
"""

from __future__ import annotations

import logging
from typing import Any

import kopf
from pydantic import ValidationError

from .controller import Controller
from .kube import KubeApi, make_client
from .metrics import Metrics
from .model import GROUP, VERSION
from .settings import OperatorSettings

log = logging.getLogger(__name__)
COMPONENT = "armnet-operator"


def connection_info(api_client: Any) -> kopf.ConnectionInfo:
    """kopf's watches use the same identity and endpoint as our writes."""
    cfg = api_client.configuration
    bearer = (cfg.api_key or {}).get("authorization") or (cfg.api_key or {}).get("BearerToken")
    token = bearer.split(" ", 1)[1] if bearer and " " in bearer else bearer
    return kopf.ConnectionInfo(
        server=cfg.host,
        ca_path=cfg.ssl_ca_cert,
        insecure=not cfg.verify_ssl,
        certificate_path=cfg.cert_file,
        private_key_path=cfg.key_file,
        token=token,
    )


def build_registry(settings: OperatorSettings) -> tuple[kopf.OperatorRegistry, Controller]:
    api_client = make_client(settings.kubeconfig)
    controller = Controller(settings, KubeApi(api_client, COMPONENT, settings.identity), Metrics())
    registry = kopf.OperatorRegistry()

    @kopf.on.login(registry=registry)
    def login(**_: Any) -> kopf.ConnectionInfo:
        return connection_info(api_client)

    @kopf.on.startup(registry=registry)
    async def start(settings: kopf.OperatorSettings, **_: Any) -> None:
        settings.posting.enabled = False  # we post our own Events, with our reasons
        settings.watching.server_timeout = 60
        settings.watching.reconnect_backoff = 0.5
        settings.batching.batch_window = 0.01
        controller.metrics.serve(controller.settings.metrics_port, controller.settings.metrics_address)
        controller.start()

    @kopf.on.cleanup(registry=registry)
    async def stop(**_: Any) -> None:
        await controller.stop()
        controller.metrics.close()

    @kopf.on.event(GROUP, VERSION, "robotjobs", registry=registry)
    async def job_event(event: kopf.RawEvent, body: kopf.Body, **_: Any) -> None:
        try:
            controller.cache.on_job(event.get("type"), body)
        except ValidationError as error:
            raise kopf.PermanentError(f"RobotJob not understood; fix its spec: {error}") from error

    @kopf.on.event(GROUP, VERSION, "cells", registry=registry)
    async def cell_event(event: kopf.RawEvent, body: kopf.Body, **_: Any) -> None:
        try:
            controller.cache.on_cell(event.get("type"), body)
        except ValidationError as error:
            raise kopf.PermanentError(f"Cell not understood; fix its spec: {error}") from error

    return registry, controller
