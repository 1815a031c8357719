"""armnet runtime SDK, used inside customer containers on a cell.

The customer-facing surface is the ``@main`` decorator and :class:`Context`;
the container's entrypoint is the ``armnet-runtime`` console script, which
loads the script, builds the context and calls the ``@main`` function::

    from armnet_runtime import main, Context

    @main
    def run(ctx: Context):
        ctx.report_progress("starting")
        return {"success_rate": 1.0}

The wire types of :mod:`armnet_core` are re-exported here. Importing this
package loads only the standard library and pydantic; numpy, opencv and
LeRobot are imported lazily by the features that need them.
"""

from armnet_core.models import (
    BIMANUAL_SO101_EMBODIMENT,
    SO101_EMBODIMENT,
    Embodiment,
    Job,
    JobResult,
    JobSpec,
    JobStatus,
    RemoteExecutionError,
    Task,
    TerminalStatus,
)

from armnet_runtime.context import (
    BimanualCalibrationLayout,
    Cell,
    CompletionStatus,
    Context,
    ResetTimeoutException,
    RuntimeArm,
    Volume,
    require_so101_embodiment,
)
from armnet_runtime.decorator import MainRegistrationError, main

__all__ = [
    "BIMANUAL_SO101_EMBODIMENT",
    "SO101_EMBODIMENT",
    "BimanualCalibrationLayout",
    "Cell",
    "CompletionStatus",
    "Context",
    "Embodiment",
    "Job",
    "JobResult",
    "JobSpec",
    "JobStatus",
    "MainRegistrationError",
    "RemoteExecutionError",
    "ResetTimeoutException",
    "RuntimeArm",
    "Task",
    "TerminalStatus",
    "Volume",
    "main",
    "require_so101_embodiment",
]
