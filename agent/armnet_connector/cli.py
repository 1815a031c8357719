"""``armnet connector``: run the connector sidecar for one cell until SIGTERM.

This module owns the command line: it loads the config, wires the operator
inputs (a file, stdin, the terminal or auto-confirm) and turns SIGTERM/SIGINT
into a clean stop (torque off if configured, devices closed, sockets removed).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
import time
from types import FrameType

from .config import load_config
from .connector import Connector, stop_budget_s
from .fast_exit import exit_after_clean_stop
from .inputs import InputFeeder, LocalOperatorInputs, terminal_prompt


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="connector config file (JSON or YAML; see docs/connector.md)")
    parser.add_argument("--socket-dir", required=True, help="directory for robot.sock and operator.sock")
    parser.add_argument(
        "--auto-confirm-reset", action="store_true",
        help="confirm every reset at once (scripted runs); default: ask on the terminal",
    )
    parser.add_argument(
        "--inputs", metavar="FILE",
        help="JSON-lines operator inputs (teleop_action, teleop_event, outcome, stop, confirm_reset); '-' for stdin",
    )
    parser.add_argument("--log-level", default="INFO", help="logging level (default INFO)")


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        config = load_config(args.config)
    except (OSError, ValueError) as exc:
        print(f"armnet connector: cannot load {args.config}: {exc}", file=sys.stderr)
        return 2
    inputs = LocalOperatorInputs(
        auto_confirm_reset=args.auto_confirm_reset,
        on_reset_requested=None if args.auto_confirm_reset or args.inputs else terminal_prompt,
    )
    if args.inputs:
        InputFeeder(inputs, args.inputs).start()
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    # Started first: at stop time the host may be out of threads, and the watchdog
    # must not depend on starting one then.
    stopping = _exit_if_stop_hangs(stop_budget_s(config.grace_period_seconds))
    with Connector(config, args.socket_dir, inputs=inputs, on_grace_expired=stop.set):
        print(f"armnet connector: serving {args.socket_dir}/robot.sock and operator.sock", file=sys.stderr, flush=True)
        # Python runs a signal handler in the main thread only, and the kernel may
        # deliver SIGTERM to any thread: a wait with no timeout can miss it for as
        # long as the main thread sleeps. Waking up often lets the handler run.
        while not stop.wait(SIGNAL_POLL_S):
            pass
        stopping.set()
    exit_after_clean_stop(0)  # torque is off and the sockets are gone: skip the interpreter's slow teardown


SIGNAL_POLL_S = 0.1


def _exit_if_stop_hangs(budget_s: float) -> threading.Event:
    """A last resort, armed by setting the returned event: if the clean stop has not ended
    within ``budget_s`` after that, exit non-zero rather than hold the cell past the
    host's kill (which would skip our cleanup)."""
    stopping = threading.Event()

    def watch() -> None:
        stopping.wait()
        time.sleep(budget_s)
        print(
            f"armnet connector: a clean stop did not finish within {budget_s:g} s; exiting now",
            file=sys.stderr, flush=True,
        )
        os._exit(70)

    threading.Thread(target=watch, name="armnet-stop-watchdog", daemon=True).start()
    return stopping
