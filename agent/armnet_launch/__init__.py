"""How a job is launched on a cell, shared by local runs (``armnet run``) and the node agent.

- ``cell_spec`` (pure): a simulated cell's shape, its directory layout, the
  ``ARMNET_CELL_CONFIG`` document and the job's exact env vars.
- ``plan`` (pure): the customer container as data (``ContainerSpec``), the
  labels that tie it to a cell and a job, the env size check.
- ``log_recovery`` (pure): what a followed container log missed.
- ``container``: the container-engine launcher (Docker API; Podman in tests).
- ``sim_cell``: the in-process simulator + connector of one job.

Supervision of the launched job (clock, grace, output, result) is
``armnet_launch.supervise``.
"""

#: The modules other packages import (local runs and the node agent); the rest are this package's own.
__all__ = [
    "cell_spec",
    "container",
    "plan",
    "pod",
    "pod_spec",
    "sidecar",
    "sim_cell",
    "supervise",
]
