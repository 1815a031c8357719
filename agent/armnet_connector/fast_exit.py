"""Ending a connector process once its clean stop is done, without the interpreter's teardown.

Measured on a 2-core host at load ~7: ``armnet connector`` logs "connector stopped" 10-30 ms
after SIGTERM, and the interpreter's teardown of what LeRobot imports (torch among them) then
takes 6.5 to more than 20 s. Everything the stop owes the cell is done by then (torque off
and read back, the sockets removed, the record printed); the teardown would only hold the
pod's end, the agent's terminal status and the host's stop, and a host that kills a process
it thinks is hung (the kubelet after the pod's grace period) cannot tell a slow teardown
from a stop that never ran.
"""

from __future__ import annotations

import logging
import os
import sys
from typing import NoReturn


def exit_after_clean_stop(code: int) -> NoReturn:
    """Flush what the process printed and logged, then end it at once with ``code``."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken pipe: nothing more can be said on it
            pass
    os._exit(code)
