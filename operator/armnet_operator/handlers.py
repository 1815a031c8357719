"""The kopf edge: watch RobotJobs and Cells into the cache, run the controller.

Thin on purpose. Handlers only parse and store; all decisions happen in the
reconcile pass. Each call of ``build_registry`` makes an independent operator
(its own registry, cache and metrics), so tests can run two replicas in one
process. No ``on.field`` chains, no kopf-managed finalizers or annotations.
"""

from __future__ import annotations

import asyncio
import logging
import signal
import sys
from collections.abc import Callable
from typing import Any

import kopf
from armnet_core.api import CELLQUOTAS, CELLS, GROUP, ROBOTJOBS, VERSION

from .controller import Controller
from .errors import PermanentError
from .kube import KubeApi, make_client
from .metrics import Metrics
from .outputs_store import OutputsStore
from .settings import OperatorSettings
from .webhook import make_webhook

log = logging.getLogger(__name__)
COMPONENT = "armnet-operator"
API_SERVER_MAX_JSON_DEPTH = 10_000
"""The API server decodes JSON up to this nesting (Go's encoding/json); anything it stores may be this deep."""


def allow_deep_json() -> None:
    """Let the watch decode every object the API server can store.

    kopf decodes watch events with ``json.loads``, whose C scanner counts
    against the interpreter's recursion limit (1,000 by default): a RobotJob
    with args nested ~1,000 levels deep broke the watch stream, and kopf
    re-listed into the same error while the object existed. The operator's own
    code never recurses over ``spec.args`` (``args.measure`` is iterative), so
    only the decoder needs the headroom; the job itself fails on the depth limit.
    """
    wanted = API_SERVER_MAX_JSON_DEPTH + 2_000
    if sys.getrecursionlimit() < wanted:
        sys.setrecursionlimit(wanted)


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


def build_registry(
    settings: OperatorSettings, stop_flag: asyncio.Event | None = None
) -> tuple[kopf.OperatorRegistry, Controller]:
    """The kopf registry and its controller.

    ``stop_flag`` (kopf.run's) is raised when the reconcile loop ends by itself, so
    kopf stops and the process exits non-zero, and again at cleanup whatever stopped
    kopf: kopf waits for its own stop flag in a task that it otherwise gives 5 s to end
    before cancelling it, which made every SIGTERM take 5 s longer.
    """

    def on_death(_error: BaseException | None) -> None:
        if stop_flag is not None:
            stop_flag.set()

    def on_resources_back() -> None:
        _note_termination_during_restart(controller)
        if stop_flag is not None:
            stop_flag.set()

    allow_deep_json()
    metrics = Metrics()
    webhook = make_webhook(metrics, settings)  # loads the certificate now: a bad path fails at start
    api_client = make_client(settings.kubeconfig)
    api = KubeApi(api_client, COMPONENT, settings.identity, outputs=OutputsStore.from_env())
    controller = Controller(settings, api, metrics, on_death=on_death, on_resources_back=on_resources_back)
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
        if webhook is not None:
            try:
                await webhook.start()
            except PermanentError as error:
                # Exit non-zero rather than run without the webhook the chart registered.
                # (A failed kopf startup activity leaves the process hanging, so stop it ourselves.)
                log.critical("%s; exiting", error)
                controller.dead, controller.died = True, error
                on_death(error)
                return
        controller.start()

    @kopf.on.cleanup(registry=registry)
    async def stop(**_: Any) -> None:
        if webhook is not None:
            await webhook.stop()
        await controller.stop()  # the pass in flight ends first: it may still queue Events
        await asyncio.to_thread(api.close)  # its Events out (bounded), the poster joined: no thread in a request at exit
        controller.metrics.close()
        if stop_flag is not None:
            stop_flag.set()

    @kopf.on.event(GROUP, VERSION, ROBOTJOBS, registry=registry)
    async def job_event(event: kopf.RawEvent, body: kopf.Body, **_: Any) -> None:
        _store(controller, "RobotJob", body, lambda: controller.cache.on_job(event.get("type"), body))

    @kopf.on.event(GROUP, VERSION, CELLS, registry=registry)
    async def cell_event(event: kopf.RawEvent, body: kopf.Body, **_: Any) -> None:
        _store(controller, "Cell", body, lambda: controller.cache.on_cell(event.get("type"), body))

    @kopf.on.event(GROUP, VERSION, CELLQUOTAS, registry=registry)
    async def quota_event(event: kopf.RawEvent, body: kopf.Body, **_: Any) -> None:
        _store(controller, "CellQuota", body, lambda: controller.cache.on_quota(event.get("type"), body))

    return registry, controller


def _note_termination_during_restart(controller: Controller) -> None:
    """A SIGTERM while kopf stops for a restart must end the process, not start kopf again.

    kopf's own handler resolves a future nobody awaits once its stop flag is raised;
    ours (installed on the same loop, replacing kopf's) marks the controller, and the
    CLI exits instead of restarting. Outside the main thread there are no signals to take.
    """
    def terminated() -> None:
        controller.terminated = True

    try:
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(signum, terminated)
    except (RuntimeError, ValueError, NotImplementedError):
        return


def _store(controller: Controller, kind: str, body: Any, store: Callable[[], None]) -> None:
    """Put one watch event into the cache; an object that cannot be read is logged and counted, never fatal.

    ``parse_job`` reads bad spec and status fields as failures of the job
    itself, so this is the last net (e.g. metadata without a name).
    """
    try:
        store()
    except Exception as error:  # noqa: BLE001 - one object must never stop the watch
        meta = body.get("metadata") or {}
        name = "/".join(str(part) for part in (meta.get("namespace"), meta.get("name")) if part)
        controller.metrics.object_errors.labels(kind).inc()
        log.error("%s %s could not be read; it is left out of scheduling: %s", kind, name, error)
