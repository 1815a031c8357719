"""The RobotJob, Cell and CellQuota bodies the client reads: the platform's one set of models (``armnet_core.resources``).

The client's boundary with the CRDs: the models accept what the API server sends
(camelCase, fields missing while the operator or the agent has not written them yet,
unknown fields ignored), and nothing else leaves the client's reads unvalidated. The
mapping to the SDK's ``Job``/``JobResult`` is in ``mapping``.
"""

from __future__ import annotations

from armnet_core.resources import (
    Cell,
    CellQueue,
    CellQuota,
    CellSpec,
    CellStatus,
    Condition,
    JobArtifacts,
    Metadata,
    MonitorVerdict,
    RobotJob,
    RobotJobResult,
    RobotJobSpec,
    RobotJobStatus,
    Rollout,
    RolloutRecord,
)

__all__ = [
    "Cell",
    "CellQueue",
    "CellQuota",
    "CellSpec",
    "CellStatus",
    "Condition",
    "JobArtifacts",
    "Metadata",
    "MonitorVerdict",
    "RobotJob",
    "RobotJobResult",
    "RobotJobSpec",
    "RobotJobStatus",
    "Rollout",
    "RolloutRecord",
]
