"""LeRobot's own commands, started inside a job, reach the cell through its connector.

A job may run LeRobot's tools (``lerobot-record``, ``lerobot-replay``, ...) as
subprocesses, or call their ``main()``. Such an interpreter never passes through
``armnet-runtime``'s ``@main``, which installs the LeRobot import swap, so the runtime
image runs :func:`activate` at every interpreter start (``armnet_lerobot_in_job.pth``,
written by ``images/runtime/Containerfile``). It acts only in a job's container: the
platform sets ``ARMNET_LEROBOT_TOOLS=remote`` in every job's env and in no other
process's (a connector drives the real bus; ``armnet_connector.policed_bus`` refuses to
start on a swapped class). Then it installs the swap, so ``--robot.port`` names the
cell's connector endpoint (``ctx.cell.robot_port``, in ``$ARMNET_CELL_CONFIG``), and it
refuses at once the tools that would rewrite what belongs to the cell:

- ``lerobot-calibrate``: the arm's calibration is the cell's, read-only in the job,
  unless the cell's owner allows calibration jobs (``ARMNET_CALIBRATION_JOBS=1``, from
  the Cell's ``spec.allowCalibrationJobs``);
- ``lerobot-setup-motors``: it rewrites servo ids and the baud rate.

Without this the connector still refuses their writes, but only after the tool's first
prompt has read the job's empty stdin: the job ended on an ``EOFError`` that explained
nothing. Inactive, it costs one environment lookup; it never raises into the
interpreter's start (a failure is one warning on stderr).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Mapping
from types import ModuleType
from typing import Any, NoReturn

from armnet_runtime import env

#: ``ARMNET_LEROBOT_TOOLS`` in a job's env: LeRobot's tools talk to the cell through the connector.
REMOTE = "remote"

CALIBRATE_REFUSAL = (
    "armnet: lerobot-calibrate is refused in this job: the arm's calibration belongs to the cell. "
    "The cell's calibration is read-only in the job, at $ARMNET_CALIBRATION_DIR (ctx.cell.calibration_dir): "
    "point the robot's calibration_dir there and LeRobot uses it as it is. Only a cell whose owner allows "
    "calibration jobs (Cell spec.allowCalibrationJobs) runs lerobot-calibrate."
)
SETUP_MOTORS_REFUSAL = (
    "armnet: lerobot-setup-motors is refused in this job: it rewrites the servos' ids and baud rate, which "
    "belong to the cell (its motor table comes from the Cell, never from a job)."
)

#: (module, the names its command runs through, the refusal, refused unless this env var is "1").
TOOLS: tuple[tuple[str, tuple[str, ...], str, str | None], ...] = (
    ("lerobot.scripts.lerobot_calibrate", ("main", "calibrate"), CALIBRATE_REFUSAL, env.CALIBRATION_JOBS),
    ("lerobot.scripts.lerobot_setup_motors", ("main", "setup_motors"), SETUP_MOTORS_REFUSAL, None),
)


def in_a_job(environ: Mapping[str, str] = os.environ) -> bool:
    return environ.get(env.LEROBOT_TOOLS) == REMOTE and not environ.get(env.LOCAL_CONTAINER)


def activate(environ: Mapping[str, str] = os.environ, *, swap_outside_a_job: bool = False) -> bool:
    """In a job's container: install the import swap and the refusals; True when in a job.

    ``swap_outside_a_job``: install the swap anyway (``armnet-runtime``, whose every run is
    a job's, also where an older launcher did not set ``ARMNET_LEROBOT_TOOLS``); the
    refusals stay for a job's container, whose cell they protect.
    """
    job = in_a_job(environ)
    if not (job or swap_outside_a_job):
        return False
    from armnet_runtime.lerobot.import_swap import install_lerobot_remote_mode

    install_lerobot_remote_mode()
    if job:
        install_tool_refusals(environ)
    return job


def install_tool_refusals(environ: Mapping[str, str] = os.environ) -> list[str]:
    """Refuse the cell-owned tools when the job imports them (or now, if it already has); their module names."""
    from armnet_runtime.lerobot import import_hook

    refused = []
    for module_name, names, why, allowed_by in TOOLS:
        if allowed_by is not None and environ.get(allowed_by) == "1":
            continue
        refuse = _refuse_in(names, why)
        if module_name in sys.modules:
            refuse(sys.modules[module_name])
        elif module_name not in import_hook.watched():
            import_hook.when_imported(module_name, refuse)
        refused.append(module_name)
    return refused


def _refuse_in(names: tuple[str, ...], why: str) -> Callable[[ModuleType], None]:
    def refused(*_args: Any, **_kwargs: Any) -> NoReturn:
        raise SystemExit(why)

    def refuse(module: ModuleType) -> None:
        for name in names:
            setattr(module, name, refused)

    return refuse


#: The ``.pth`` line: it looks at the environment before importing anything, so an interpreter
#: outside a job (pip, a platform process) pays one lookup.
PTH_LINE = (
    f"import os; os.environ.get({env.LEROBOT_TOOLS!r}) == {REMOTE!r} and "
    "__import__('armnet_runtime.lerobot.in_job', fromlist=['in_job'])._activate_at_start()\n"
)
PTH_NAME = "armnet_lerobot_in_job.pth"  # after armnet.pth (which puts armnet's packages on the path)


def write_pth(site_packages: str | None = None) -> str:
    """Write the ``.pth`` into ``site_packages`` (default: this interpreter's); its path."""
    import sysconfig

    path = os.path.join(site_packages or sysconfig.get_path("purelib"), PTH_NAME)
    with open(path, "w", encoding="utf-8") as out:
        out.write(PTH_LINE)
    return path


def _activate_at_start() -> None:
    """The ``.pth`` entry point: never lets a failure stop the interpreter from starting."""
    try:
        activate()
    except Exception as exc:  # noqa: BLE001 - a job must still start; its LeRobot calls then fail with the cause
        print(f"armnet: LeRobot remote mode could not be installed at start: {exc!r}", file=sys.stderr)


__all__ = [
    "CALIBRATE_REFUSAL",
    "PTH_LINE",
    "PTH_NAME",
    "REMOTE",
    "SETUP_MOTORS_REFUSAL",
    "activate",
    "in_a_job",
    "install_tool_refusals",
    "write_pth",
]
