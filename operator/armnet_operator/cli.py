"""``armnet operator``: run the scheduling operator (flags override ARMNET_OPERATOR_* env)."""

from __future__ import annotations

import argparse
import asyncio
import logging

from armnet_core.backoff import BackoffPolicy

from .errors import PermanentError
from .settings import ENV_PREFIX, OperatorSettings, load_settings
from .termination import Termination


def add_arguments(parser: argparse.ArgumentParser) -> None:
    for name, field in OperatorSettings.model_fields.items():
        if name == "identity":
            continue
        flag = "--" + name.replace("_", "-")
        env = ENV_PREFIX + name.upper()
        default = field.get_default(call_default_factory=False)
        help_text = f"{field.description or name} (env {env}; default {default!r})"
        parser.add_argument(flag, dest=name, default=None, help=help_text)
    parser.add_argument("--identity", default=None, help="replica name in the leader Lease (default host-pid)")
    parser.add_argument("--verbose", action="store_true", help="debug logging")


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not args.verbose:
        # kopf logs every handled watch event at INFO: thousands of lines a second under
        # load, and measurably slower binds (the log writes share the event loop).
        logging.getLogger("kopf.objects").setLevel(logging.WARNING)
    overrides = {name: getattr(args, name, None) for name in OperatorSettings.model_fields}
    try:
        settings = load_settings(overrides)
    except PermanentError as error:
        logging.getLogger("armnet.operator").error("%s", error)
        return 2
    import kopf  # heavy: only when actually running

    from .handlers import build_registry

    log = logging.getLogger("armnet.operator")
    failures = 0
    termination = Termination().install()
    terminated = termination.requested
    while True:
        if terminated.is_set():
            log.info("terminated between two runs of the operator's watches; exiting")
            return 0
        # If the reconcile loop ever ends by itself, stop kopf and exit non-zero: a
        # process that only watches would sit in the Lease while nothing is scheduled.
        # An asyncio.Event, never a threading.Event: kopf waits for a threading.Event in an
        # executor thread that nothing wakes when kopf stops for another reason (SIGTERM, a
        # failed watch), and asyncio.run then waits for that thread forever: the process hung
        # after its cleanup. The flag is only set from the loop.
        stop = termination.stop_flag = asyncio.Event()
        try:
            registry, controller = build_registry(settings, stop_flag=stop)
        except PermanentError as error:  # e.g. the webhook's certificate cannot be loaded
            log.error("%s", error)
            return 2
        try:
            kopf.run(
                registry=registry,
                standalone=True,  # leader election is ours (a Lease), not kopf peering
                clusterwide=not settings.namespaces,
                namespaces=settings.namespaces,
                stop_flag=stop,
            )
        except Exception as error:  # noqa: BLE001 - kopf's reactor failed; see restart_after
            termination.install()
            if controller.dead:
                return 1
            failures += 1
            wait = restart_after(failures)
            if wait is None:
                log.error("kopf failed %d times in a row (last: %s); exiting so the Deployment restarts "
                          "the operator", failures, str(error)[:300])
                return 1
            log.error("kopf stopped (%s); starting the operator's watches and reconcile loop again in "
                      "%.0f s", str(error)[:300], wait)
            terminated.wait(wait)  # a SIGTERM meanwhile ends the wait and the process
            continue
        termination.install()
        if controller.restart_requested and not controller.terminated:
            failures = 0
            log.info("starting the operator's watches and reconcile loop again")
            continue
        return 1 if controller.dead else 0


MAX_RESTARTS = 5
#: kopf run again after 1, 2, 4, 8, 16 s; past ``MAX_RESTARTS`` the Deployment restarts the process.
RESTART_BACKOFF = BackoffPolicy(first_s=1.0, max_s=30.0)


def restart_after(failures: int) -> float | None:
    """Seconds before the operator runs kopf again after ``failures`` failures in a row (None: give up).

    kopf stops its whole reactor when one watch fails: a RobotJob watch that reconnects
    between a CRD's deletion and kopf noticing it gets HTTP 404 and ends the operator's
    loop (kopf's own observer documents this race). The state worth keeping lives in the
    API server, so a fresh registry and controller in the same process lose nothing.
    """
    return None if failures > MAX_RESTARTS else RESTART_BACKOFF.delay(failures)
