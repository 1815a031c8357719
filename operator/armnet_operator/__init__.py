"""The kopf operator (``armnet operator``): binds RobotJobs to free Cells, queues the rest.

Pure decisions (``scheduling``, ``lifecycle``, ``quota``, ``fairshare``, ...) plan each
pass over a snapshot; ``handlers`` feed the snapshot from kopf and ``reconcile`` writes
the plan. See docs/operator.md.
"""

#: The modules other packages import (none: the CLI starts it by name); the rest are this package's own.
__all__: list[str] = []
