"""Job-process supervision shared by ``armnet run`` (local mode) and the node agent.

The package owns one job process from start to exit: its env, its output lines
(live, with marker parsing), its deadline and grace window, and the final
``JobResult``. It never talks to hardware or to the connector directly: the
host passes callbacks (open the grace window, report progress) instead.

Layers: ``tail``, ``observe`` and ``outcome`` are pure; ``process`` and
``supervisor`` do the I/O.
"""

from armnet_launch.supervise.observe import OutputEvent, OutputObserver
from armnet_launch.supervise.outcome import RunFacts, assemble_result
from armnet_launch.supervise.supervisor import (
    JobHooks,
    LaunchedJob,
    SubprocessJob,
    SupervisorLimits,
    infra_failure,
    supervise,
)
from armnet_launch.supervise.tail import BoundedTail

__all__ = [
    "BoundedTail",
    "JobHooks",
    "LaunchedJob",
    "OutputEvent",
    "OutputObserver",
    "RunFacts",
    "SubprocessJob",
    "SupervisorLimits",
    "assemble_result",
    "infra_failure",
    "supervise",
]
