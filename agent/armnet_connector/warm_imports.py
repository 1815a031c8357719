"""Importing LeRobot's device classes while the connector starts, not on a job's first request.

Profiling the first remote ``FeetechMotorsBus(...)`` showed where its 1.35–1.7 s
(seconds more on a busy machine) went: the connector imported
``lerobot.motors.feetech`` lazily on that first ``create``, and that module pulls in
torch and datasets through ``lerobot.utils.utils``; the bus constructor itself
costs microseconds. Importing in a background thread from ``Connector.start``
overlaps that cost with the job's own start-up (which imports LeRobot too).
A ``create`` that arrives mid-import waits on Python's per-module import lock
for the rest of it, never imports twice, and an import that fails here fails
again, with its real error, in the request that needs it.

Some of those imports edit the process environment: numpy's first import (before
2.4, which uses ``putenv`` instead) sets ``OPENBLAS_MAIN_FREE`` and deletes it again. Done in this thread while another
thread walks ``os.environ`` (``requests`` reads proxy settings from it on every
Docker API call), the walk meets a key that is gone: a job failed to launch with
``KeyError: 'OPENBLAS_MAIN_FREE'``. So every process that starts a connector calls
:func:`import_before_threads` first, while it has one thread.
"""

from __future__ import annotations

import importlib
import logging
import threading
import time

log = logging.getLogger(__name__)

DEVICE_MODULES = ("lerobot.motors.feetech", "lerobot.cameras.opencv")
"""What ``hardware.create_feetech`` / ``create_camera`` import on a request."""

ENVIRONMENT_EDITING_MODULES = ("numpy",)
"""Modules whose first import edits ``os.environ`` (numpy: ``OPENBLAS_MAIN_FREE``)."""


def import_before_threads(modules: tuple[str, ...] = ENVIRONMENT_EDITING_MODULES) -> None:
    """Import ``modules`` now, in the calling thread: call it before the process starts threads.

    Later imports of them (the warm imports, a job's first request) find them in
    ``sys.modules`` and leave the environment alone.
    """
    for name in modules:
        importlib.import_module(name)


def start_warm_imports(modules: tuple[str, ...] = DEVICE_MODULES) -> threading.Thread:
    """Import ``modules`` in a daemon thread; returns the thread (tests join it)."""

    def run() -> None:
        for name in modules:
            started = time.monotonic()
            try:
                importlib.import_module(name)
            except Exception as exc:  # noqa: BLE001 - the request that needs it reports the real error
                log.warning("warming %s failed (%s); a job's first device request will retry it", name, exc)
                continue
            log.debug("imported %s in %.2f s", name, time.monotonic() - started)

    thread = threading.Thread(target=run, name="armnet-warm-imports", daemon=True)
    thread.start()
    return thread
