"""The Kubernetes API's vocabulary, defined once for every package that speaks it.

The operator, the node agent, the launch library, the FMS and the customer's client
all read and write RobotJobs and Cells; each used to declare the group, the version
and the phases itself. They import them from here, and
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

__all__ = [
    "ACTIVE_PHASES",
    "API_VERSION",
    "CELLQUOTAS",
    "CELLS",
    "GROUP",
    "PHASES",
    "ROBOTJOBS",
    "TERMINAL_PHASES",
    "VERSION",
]
