"""armnet_core: the wire models shared by the SDK, the agent and the operator."""

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

__all__ = [
    "BIMANUAL_SO101_EMBODIMENT",
    "SO101_EMBODIMENT",
    "Embodiment",
    "Job",
    "JobResult",
    "JobSpec",
    "JobStatus",
    "RemoteExecutionError",
    "Task",
    "TerminalStatus",
]
