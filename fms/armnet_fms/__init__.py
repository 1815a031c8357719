"""armnet FMS: the cell operator's web page (``armnet fms``).

The person standing at the robots sees every cell they look after, confirms
resets, marks rollouts, stops a job and cordons a cell. Pure parts (``view``,
``actions``, ``auth``) decide; ``kube``, ``bus`` and ``app`` do the I/O.
"""

#: The modules other packages import (local runs' page); the rest are this package's own.
__all__ = [
    "local",
    "telemetry",
]
