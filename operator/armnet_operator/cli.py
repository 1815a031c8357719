"""``armnet operator``: run the scheduling operator (flags override ARMNET_OPERATOR_* env)."""

from __future__ import annotations

import argparse
import logging
import threading

from .errors import PermanentError
from .settings import ENV_PREFIX, OperatorSettings, load_settings


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

    # If the reconcile loop ever ends by itself, stop kopf and exit non-zero: a
    # process that only watches would sit in the Lease while nothing is scheduled.
    stop = threading.Event()
    try:
        registry, controller = build_registry(settings, on_death=lambda _error: stop.set())
    except PermanentError as error:  # e.g. the webhook's certificate cannot be loaded
        logging.getLogger("armnet.operator").error("%s", error)
        return 2
    kopf.run(
        registry=registry,
        standalone=True,  # leader election is ours (a Lease), not kopf peering
        clusterwide=not settings.namespaces,
        namespaces=settings.namespaces,
        stop_flag=stop,
    )
    return 1 if controller.dead else 0
