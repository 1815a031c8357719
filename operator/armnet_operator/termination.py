"""SIGTERM and SIGINT while no kopf run owns them: the operator exits 0, never dies of -15.

Why: each ``kopf.run`` installs its signal handlers on its own event loop, a little
after that loop starts, and closing the loop puts the default action back. Between
two runs (an in-process restart: a new registry and controller, a backoff wait) and
in the first moments of a run, a SIGTERM would otherwise kill the process with the
default action instead of the clean stop the Deployment asked for.
"""

from __future__ import annotations

import asyncio
import signal
import threading
from types import FrameType


class Termination:
    """Our handler for the gaps: it records the request and stops the kopf run starting, if any.

    ``install`` is called before the first run and after each one (kopf's own handlers
    replace it while a run owns the loop). ``stop_flag`` is the current run's stop flag.
    """

    def __init__(self) -> None:
        self.requested = threading.Event()
        self.stop_flag: asyncio.Event | None = None

    def install(self) -> Termination:
        if threading.current_thread() is threading.main_thread():  # signals reach the main thread only
            for signum in (signal.SIGTERM, signal.SIGINT):
                signal.signal(signum, self._on_signal)
        return self

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.requested.set()
        try:
            loop = asyncio.get_running_loop()  # a run starting, before kopf put its own handlers in
        except RuntimeError:
            return  # between runs: the CLI sees ``requested`` before it would start another
        if self.stop_flag is not None:
            loop.call_soon_threadsafe(self.stop_flag.set)
