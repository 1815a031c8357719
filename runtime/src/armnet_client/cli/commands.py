"""The client's subcommand table, read by ``armnet_cli.main`` (importing it loads nothing heavy)."""

from __future__ import annotations

COMMANDS: tuple[tuple[str, str, str], ...] = (
    ("submit", "armnet_client.cli.submit", "create a RobotJob and follow it (or --detach)"),
    ("get", "armnet_client.cli.get", "list RobotJobs, or show one, with queue reason and position"),
    ("cells", "armnet_client.cli.cells", "list Cells: phase, current job, failing health, heartbeat"),
    ("quota", "armnet_client.cli.quota", "your CellQuotas: share, cells held and borrowed, jobs waiting, credits"),
    ("result", "armnet_client.cli.result", "print a job's JobResult; exit 0 succeeded, 1 other end, 2 running"),
    ("cancel", "armnet_client.cli.cancel", "cancel a RobotJob (queued: at once; running: within grace)"),
    ("logs", "armnet_client.cli.logs", "print a job's output from its first line; -f to follow"),
    ("teleop", "armnet_client.cli.teleop", "drive a running job's arm from a leader arm (or --leader sim)"),
    ("artifacts", "armnet_client.cli.artifacts", "where a job's output went; --files lists it, --download DIR fetches it"),
    ("view", "armnet_client.cli.view", "replay a job's Rerun data into a viewer, an .rrd (--save) or JSON (--dump)"),
)
"""(name, module, one-line help) of each client subcommand."""
