"""``armnet run SCRIPT``: run a job script on this machine against a simulated cell.

Thin edge: parse flags, build the cell spec (``cell_spec``), start the local
cell (``session``), launch the job (subprocess, or container with ``--image``),
supervise it (``armnet_launch.supervise``) and print the ``JobResult``.
Exit code 0 iff the job succeeded.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import signal
import sys
import tempfile
import threading
import uuid
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from armnet_connector.warm_imports import import_before_threads
from armnet_core import JobResult, JobStatus
from armnet_launch.cell_spec import (
    DEFAULT_TASK,
    EMBODIMENT_PRESET,
    LocalCellError,
    LocalCellSpec,
    build_job_env,
    load_cell_file,
    plan_layout,
    resolve_spec,
)
from armnet_launch.supervise import JobHooks, SupervisorLimits, infra_failure, supervise

from armnet_local.render import TerminalRenderer

if TYPE_CHECKING:
    from armnet_launch.sim_cell import LocalCell

DEFAULT_TIMEOUT_SECONDS = 120
#: Host variables a local subprocess keeps (a container gets none of them).
HOST_ENV_KEPT = ("PATH", "HOME", "LANG", "LC_ALL", "TERM", "TMPDIR", "VIRTUAL_ENV", "PYTHONPATH")
EXIT_USAGE = 2
PRESET_CHOICES = ("so101", "bimanual_so101")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("script", type=Path, help="the job script (a file with one @main function)")
    parser.add_argument(
        "--embodiment",
        default=None,
        help=f"robot embodiment: one of {sorted(EMBODIMENT_PRESET)} (default: the preset's)",
    )
    parser.add_argument("--task", default=None, help=f"the cell's task (default: {DEFAULT_TASK!r})")
    parser.add_argument("--args", default="{}", help="JSON object passed to the job as ctx.args")
    parser.add_argument(
        "--timeout",
        type=int,
        default=DEFAULT_TIMEOUT_SECONDS,
        help=f"job timeout in seconds (default {DEFAULT_TIMEOUT_SECONDS})",
    )
    parser.add_argument("--grace", type=float, default=None, help="grace window after the timeout, seconds (default 10)")
    parser.add_argument("--image", default=None, help="run the job in this container image (Docker API engine)")
    parser.add_argument("--json", action="store_true", help="print the JobResult as JSON on the last stdout line")
    parser.add_argument("--cell-config", type=Path, default=None, help="a local cell file (JSON/YAML) overriding the defaults")
    parser.add_argument("--preset", choices=sorted(PRESET_CHOICES), default=None, help="simulated cell preset (default so101)")
    parser.add_argument(
        "--auto-confirm-reset", action="store_true", help="confirm every ctx.cell.reset() at once (scripted runs)"
    )
    parser.add_argument(
        "--fms",
        type=int,
        default=None,
        metavar="PORT",
        help="serve the cell operator's page for this cell on http://127.0.0.1:PORT "
        "(confirm resets, mark rollouts, stop; docs/fms.md)",
    )
    parser.add_argument(
        "--output",
        type=Path,
        default=None,
        metavar="DIR",
        help="keep the job's output directory (ARMNET_OUTPUT_DIR; LeRobot datasets land in its lerobot/) "
        "here; default: a temporary directory removed after the run",
    )
    parser.add_argument(
        "--inputs",
        default=None,
        help="operator inputs as JSON lines from this file, or - for stdin "
        '(e.g. {"teleop_event": "next_episode"}, {"outcome": true}, {"confirm_reset": true})',
    )


def run(args: argparse.Namespace) -> int:
    import_before_threads()  # before the connector's and the engine client's threads (warm_imports.py)
    # Connector and simulator warnings (deadline, safety trips) go to stderr, tagged.
    logging.basicConfig(level=logging.WARNING, format="armnet run: %(message)s")
    # SIGTERM cancels like Ctrl-C: the job is killed and the cell torn down, never orphaned.
    signal.signal(signal.SIGTERM, _interrupt)
    renderer = TerminalRenderer()
    try:
        request = parse_request(args)
    except UsageError as exc:
        renderer.note(str(exc))
        return EXIT_USAGE
    result = run_local_job(request, renderer)
    print(str(result), flush=True)
    if args.json:
        print(result.model_dump_json(), flush=True)
    return 0 if result.status is JobStatus.SUCCEEDED else 1


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


class UsageError(ValueError):
    """A flag is wrong; the message says which and how to fix it."""


class LocalRunRequest:
    """The validated flags of one ``armnet run``."""

    def __init__(
        self,
        *,
        script: Path,
        spec: LocalCellSpec,
        job_args: dict[str, Any],
        timeout_seconds: int,
        image: str | None,
        auto_confirm_reset: bool,
        inputs: str | None,
        fms_port: int | None = None,
        output_dir: Path | None = None,
    ) -> None:
        self.script = script
        self.spec = spec
        self.job_args = job_args
        self.timeout_seconds = timeout_seconds
        self.image = image
        self.auto_confirm_reset = auto_confirm_reset
        self.inputs = inputs
        self.fms_port = fms_port
        self.output_dir = output_dir


def parse_request(args: argparse.Namespace) -> LocalRunRequest:
    script = Path(args.script)
    if not script.is_file():
        raise UsageError(f"no such script: {script}")
    try:
        job_args = json.loads(args.args)
    except json.JSONDecodeError as exc:
        raise UsageError(f"--args must be a JSON object: {exc}") from exc
    if not isinstance(job_args, dict):
        raise UsageError(f"--args must be a JSON object, got {type(job_args).__name__}")
    if args.timeout < 1:
        raise UsageError("--timeout must be at least 1 second")
    if args.grace is not None and args.grace < 0:
        raise UsageError("--grace cannot be negative")
    if args.inputs not in (None, "-") and not Path(args.inputs).is_file():
        raise UsageError(f"--inputs: no such file: {args.inputs}")
    try:
        cell_file = load_cell_file(args.cell_config) if args.cell_config else None
        spec = resolve_spec(
            embodiment=args.embodiment,
            preset=args.preset,
            task=args.task,
            grace_seconds=args.grace,
            cell_file=cell_file,
        )
    except LocalCellError as exc:
        raise UsageError(str(exc)) from exc
    return LocalRunRequest(
        script=script.resolve(),
        spec=spec,
        job_args=job_args,
        timeout_seconds=args.timeout,
        image=args.image,
        auto_confirm_reset=args.auto_confirm_reset,
        inputs=args.inputs,
        fms_port=getattr(args, "fms", None),
        output_dir=_output_dir(getattr(args, "output", None)),
    )


def _output_dir(path: Path | None) -> Path | None:
    """``--output``, absolute (it is mounted at the same path in a container); not a file."""
    if path is None:
        return None
    if path.exists() and not path.is_dir():
        raise UsageError(f"--output {path} is a file; name a directory (it is created if missing)")
    return path.resolve()


def run_local_job(
    request: LocalRunRequest,
    renderer: TerminalRenderer,
    inspect: Callable[[LocalCell, JobResult], None] | None = None,
) -> JobResult:
    """Start the cell, run the job under supervision, tear everything down.

    ``inspect`` sees the still-running cell and the result just before teardown
    (tests read the simulator's final joint positions there).
    """
    from armnet_launch.sim_cell import LocalCell

    spec = request.spec
    limits = SupervisorLimits(timeout_seconds=request.timeout_seconds, grace_seconds=spec.grace_seconds)
    engine = None
    if request.image is not None:
        from armnet_launch.container import EngineUnavailable, connect_engine

        try:
            engine = connect_engine()
        except EngineUnavailable as exc:
            renderer.note(str(exc))
            return infra_failure(str(exc), limits)

    run_dir = Path(tempfile.mkdtemp(prefix="armnet-run-"))
    hooks = JobHooks(on_event=renderer)
    job_id = f"local-{uuid.uuid4().hex[:12]}"
    page = None
    try:
        if request.fms_port is not None:
            page = _start_page(request.fms_port, job_id, spec.reset_timeout_seconds, hooks, renderer)
        layout = plan_layout(spec, run_dir)
        if request.output_dir is not None:
            layout = replace(layout, output_dir=request.output_dir)
        with LocalCell(
            spec,
            run_dir,
            layout=layout,
            auto_confirm_reset=request.auto_confirm_reset,
            inputs_source=request.inputs,
            on_grace_expired=hooks.kill_now.set,
            inputs=page.inputs if page is not None else None,
            timeout_s=request.timeout_seconds,
        ) as cell:
            if page is not None:
                page.cell = cell
            hooks.on_deadline = cell.pass_deadline
            hooks.on_cancel = cell.cancel
            env = build_job_env(
                spec, cell.layout, job_id=job_id, timeout_seconds=request.timeout_seconds, args=request.job_args
            )
            env["PYTHONUNBUFFERED"] = "1"
            renderer.note(
                f"job {job_id} on a simulated {spec.preset} cell ({spec.embodiment}); "
                f"timeout {request.timeout_seconds} s, grace {spec.grace_seconds:g} s"
            )
            if engine is not None:
                result = _run_in_container(engine, request, env, run_dir, limits, hooks)
            else:
                result = _run_subprocess(request, env, limits, hooks)
            if page is not None:
                page.finished(result.status.value)
            if inspect is not None:
                inspect(cell, result)
            return result
    except Exception as exc:  # noqa: BLE001 - an infra failure becomes a failed JobResult, never a trace
        renderer.note(f"the local cell failed: {exc}")
        return infra_failure(f"the local cell failed: {type(exc).__name__}: {exc}", limits)
    finally:
        if page is not None:
            page.stop()
        shutil.rmtree(run_dir, ignore_errors=True)


def _start_page(port: int, job_id: str, reset_timeout_s: float, hooks: JobHooks,
                renderer: TerminalRenderer) -> Any:
    """The cell operator's page for this run (``--fms``); its inputs replace the terminal prompt."""
    from armnet_local.fms_page import LocalPage

    page = LocalPage(port, job_id, reset_timeout_s, hooks).start()
    show = hooks.on_event

    def on_event(event: Any) -> None:
        page.observe(event)
        if show is not None:
            show(event)

    hooks.on_event = on_event
    renderer.note(f"the cell operator's page: {page.server.url}/login (token {page.server.token})")
    return page


def runtime_command(script: Path) -> list[str]:
    """``armnet-runtime SCRIPT``, preferring the one next to this interpreter (the venv's)."""
    beside = Path(sys.executable).parent / "armnet-runtime"
    program = str(beside) if beside.exists() else shutil.which("armnet-runtime")
    if program is None:
        raise FileNotFoundError(
            "armnet-runtime is not installed; run scripts/setup.sh (or pip install -e runtime)"
        )
    return [program, str(script)]


def _run_subprocess(
    request: LocalRunRequest, env: dict[str, str], limits: SupervisorLimits, hooks: JobHooks
) -> JobResult:
    from armnet_launch.supervise import SubprocessJob

    process_env = {key: os.environ[key] for key in HOST_ENV_KEPT if key in os.environ}
    process_env.update(env)
    job = SubprocessJob.start(runtime_command(request.script), process_env, cwd=str(request.script.parent))
    return _supervise_interruptible(job, limits, hooks)


def _run_in_container(
    engine: Any,
    request: LocalRunRequest,
    env: dict[str, str],
    run_dir: Path,
    limits: SupervisorLimits,
    hooks: JobHooks,
) -> JobResult:
    from armnet_launch.container import ContainerJob

    output = request.output_dir
    job = ContainerJob.start(engine, request.image or "", request.script, env, run_dir,
                             writable_mounts=(str(output),) if output is not None else ())
    try:
        return _supervise_interruptible(job, limits, hooks)
    finally:
        job.remove()


def _supervise_interruptible(job: Any, limits: SupervisorLimits, hooks: JobHooks) -> JobResult:
    """Supervise on a worker thread so Ctrl-C here cancels the job instead of orphaning it."""
    outcome: list[JobResult] = []
    done = threading.Event()

    def follow() -> None:
        try:
            outcome.append(supervise(job, limits, hooks))
        except Exception as exc:  # noqa: BLE001 - reported as an infra failure, not a trace
            job.kill()
            outcome.append(infra_failure(f"supervising the job failed: {type(exc).__name__}: {exc}", limits))
        finally:
            done.set()

    threading.Thread(target=follow, name="armnet-supervise", daemon=True).start()
    # An Event, not Thread.join: an interrupted join can report a live thread as finished.
    while not done.is_set():
        try:
            done.wait(0.2)
        except KeyboardInterrupt:
            hooks.cancel.set()
    return outcome[0]
