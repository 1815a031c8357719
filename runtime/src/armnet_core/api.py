"""The Kubernetes API's vocabulary, defined once for every package that speaks it.

The operator, the node agent, the launch library, the FMS and the customer's client
all read and write RobotJobs and Cells; each used to declare the group, the version,
the phases and the annotations it shares with another itself. They import them from here, and
``tests/unit/architecture/test_api_vocabulary.py`` keeps this module in step with
the CRDs in ``crds/`` (group, version, plurals, the phase enum).
"""

from __future__ import annotations

from armnet_core.models import JobStatus, TerminalStatus

GROUP = "armnet.io"
VERSION = "v1alpha1"
API_VERSION = f"{GROUP}/{VERSION}"

ROBOTJOBS = "robotjobs"
CELLS = "cells"
CELLQUOTAS = "cellquotas"

#: ``RobotJob.status.phase`` values, as plain strings (the SDK's ``JobStatus``).
PHASES: tuple[str, ...] = tuple(status.value for status in JobStatus)
#: A job in one of these phases holds its cell: the agent runs it.
ACTIVE_PHASES: frozenset[str] = frozenset({JobStatus.DISPATCHED.value, JobStatus.RUNNING.value})
#: A job in one of these phases has ended; nothing changes its phase again.
TERMINAL_PHASES: frozenset[str] = frozenset(status.value for status in TerminalStatus)

#: Keys on RobotJobs and Cells that one process writes and another reads.
#: The cell operator's page (FMS) writes who stopped a job; the node agent puts it in the job's error.
STOPPED_BY_ANNOTATION = f"{GROUP}/stopped-by"
#: ``armnet submit --follow`` asks for a cancel when its client is gone this long; the node agent applies it.
FOLLOWER_TIMEOUT_ANNOTATION = f"{GROUP}/follower-timeout-seconds"
#: The operator's finalizer on a RobotJob: the job's cell is released before the job is deleted.
RELEASE_CELL_FINALIZER = f"{GROUP}/release-cell"
#: The label by which the cell operator's page groups Cells (set by whoever installs the cells).
SITE_LABEL = f"{GROUP}/site"
#: Simulated cells only: ``arm/motor`` (comma-separated) of servos the node agent unplugs in the
#: simulator, so a platform team can watch the cell go unhealthy (fault injection).
SIM_UNPLUG_ANNOTATION = f"{GROUP}/sim-unplug"

#: The object store of job outputs, as the node agent reads it from its env (the chart's
#: ``artifacts`` values) and the client too (``armnet artifacts``; docs/outputs.md).
ARTIFACTS_ENDPOINT_ENV = "ARMNET_ARTIFACTS_ENDPOINT"
ARTIFACTS_BUCKET_ENV = "ARMNET_ARTIFACTS_BUCKET"
ARTIFACTS_REGION_ENV = "ARMNET_ARTIFACTS_REGION"
ARTIFACTS_ACCESS_KEY_ENV = "ARMNET_ARTIFACTS_ACCESS_KEY_ID"
ARTIFACTS_SECRET_KEY_ENV = "ARMNET_ARTIFACTS_SECRET_ACCESS_KEY"

__all__ = [
    "ARTIFACTS_ACCESS_KEY_ENV",
    "ARTIFACTS_BUCKET_ENV",
    "ARTIFACTS_ENDPOINT_ENV",
    "ARTIFACTS_REGION_ENV",
    "ARTIFACTS_SECRET_KEY_ENV",
    "ACTIVE_PHASES",
    "API_VERSION",
    "CELLQUOTAS",
    "CELLS",
    "FOLLOWER_TIMEOUT_ANNOTATION",
    "GROUP",
    "PHASES",
    "RELEASE_CELL_FINALIZER",
    "ROBOTJOBS",
    "SIM_UNPLUG_ANNOTATION",
    "SITE_LABEL",
    "STOPPED_BY_ANNOTATION",
    "TERMINAL_PHASES",
    "VERSION",
]
