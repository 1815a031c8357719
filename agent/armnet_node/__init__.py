"""The node agent (``armnet agent``): one process per robot host, one worker per Cell on it.

Pure parts: ``model`` (Cell/RobotJob parsing, the launch rule), ``plan`` (the
launch plan of a job on a cell), ``health`` (conditions from probe results),
``report`` (status writes from run facts). I/O: ``kube``, ``probes``,
``runner`` (one job), ``worker`` (one cell), ``agent`` (the loop), ``publish``
(the door to NATS), ``metrics``, ``cli``. See docs/agent.md.
"""

#: The modules other packages import (only `armnet run --fms`, .importlinter's one exception);
#: the rest are this package's own.
__all__ = [
    "metrics",
    "telemetry",
    "telemetry_sources",
]
