"""``armnet run``: a job on this machine against an in-process simulated cell.

It starts the cell simulator, simulated cameras and the real connector on a
temporary socket directory, injects exactly the env a cell injects, and runs
the script under ``armnet-runtime`` (a subprocess, or a container with
``--image``) under the shared job supervisor (``armnet_launch.supervise``).
"""

#: The modules other packages import (none: the CLI starts it by name); the rest are this package's own.
__all__: list[str] = []
