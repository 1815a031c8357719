"""``armnet-runtime SCRIPT``: the container entrypoint that runs a customer's ``@main``.

Steps, in order:

1. Install the LeRobot import swap so hardware classes route through the
   cell's connector (skipped for local-container runs, a no-op without LeRobot).
2. Put the script's directory on ``sys.path`` (sibling imports work).
3. Import the script; its ``@main`` registers the entry point.
4. Build the :class:`~armnet_runtime.Context` from the injected env vars.
5. Call the entry point with it.
6. Print its return value behind ``[armnet:result]:json``.
7. Map failures to exit codes (below) and print ``[armnet:traceback]:json``
   for a raise in user code; ``SystemExit`` from user code passes through.

Every stdout/stderr line is prefixed with an ISO-8601 UTC timestamp.
"""

from __future__ import annotations

import argparse
import gc
import importlib.util
import logging
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Optional, TextIO, cast

from armnet_runtime.context import Context, build_context
from armnet_runtime.decorator import _clear_registration, registered_main
from armnet_runtime.markers import format_result, format_traceback
from armnet_runtime.streams import TimestampedStream, emit_line

EXIT_OK = 0
EXIT_USER_RAISED = 1
EXIT_USAGE = 2
EXIT_NO_MAIN = 3
EXIT_USER_IMPORT_FAILED = 4
EXIT_BAD_CONTEXT = 5

_USER_MODULE_NAME = "__armnet_main__"


class _UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> Any:  # argparse would sys.exit(2) on its own
        raise _UsageError(message)


def _parse_args(argv: Sequence[str]) -> argparse.Namespace:
    parser = _Parser(
        prog="armnet-runtime",
        description="Run the @main function of SCRIPT with the armnet job context.",
    )
    parser.add_argument("script", help="path to the Python file that defines the @main function")
    return parser.parse_args(list(argv))


def _install_timestamped_streams() -> None:
    if not isinstance(sys.stdout, TimestampedStream):
        sys.stdout = cast(TextIO, TimestampedStream(sys.stdout))
    if not isinstance(sys.stderr, TimestampedStream):
        sys.stderr = cast(TextIO, TimestampedStream(sys.stderr))


class _StderrHandler(logging.Handler):
    """Writes to whatever ``sys.stderr`` is at emit time (the timestamped stream during a run)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
        except Exception:  # noqa: BLE001 - logging must never raise into the job
            self.handleError(record)


def _configure_sdk_logging() -> None:
    """Show the SDK's own INFO lines (e.g. what the import swap patched) on stderr.

    Only the ``armnet_runtime`` logger is configured, so the customer's own
    ``logging.basicConfig`` keeps working as usual.
    """
    sdk_logger = logging.getLogger("armnet_runtime")
    if any(isinstance(h, _StderrHandler) for h in sdk_logger.handlers):
        return
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter("armnet-runtime: %(levelname)s %(message)s"))
    sdk_logger.addHandler(handler)
    sdk_logger.setLevel(logging.INFO)
    sdk_logger.propagate = False


def _flush_streams() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass


def _load_user_script(script: str) -> None:
    path = Path(script).resolve()
    if not path.is_file():
        raise FileNotFoundError(f"script {script!r} does not exist")
    script_dir = str(path.parent)
    if script_dir not in sys.path:
        sys.path.insert(0, script_dir)
    spec = importlib.util.spec_from_file_location(_USER_MODULE_NAME, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {script!r} as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[_USER_MODULE_NAME] = module
    spec.loader.exec_module(module)


_SDK_DIR = str(Path(__file__).resolve().parent)


def _user_traceback() -> str:
    """The current exception's traceback without the SDK's and importlib's leading frames.

    The customer sees their own code first; stderr keeps the full traceback.
    """
    _, exc, tb = sys.exc_info()
    if exc is None:
        return ""
    while tb is not None:
        filename = tb.tb_frame.f_code.co_filename
        if not (filename.startswith(_SDK_DIR) or filename.startswith("<frozen importlib")):
            break
        tb = tb.tb_next
    return "".join(traceback.format_exception(type(exc), exc, tb))


def _print_traceback_marker(text: str) -> None:
    emit_line(format_traceback(text))


def _print_result(result: Any) -> None:
    emit_line(format_result(result))


def _stop_rerun(ctx: Optional[Context]) -> None:
    streamer = getattr(ctx, "_rerun_streamer", None)
    if streamer is not None:
        streamer.stop()


def run(argv: Sequence[str] | None = None) -> int:
    """Run a script's ``@main``; returns the process exit code (``EXIT_*``)."""
    try:
        args = _parse_args(sys.argv[1:] if argv is None else list(argv))
    except _UsageError as exc:
        print(f"usage: armnet-runtime SCRIPT\narmnet-runtime: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    saved = sys.stdout, sys.stderr
    _install_timestamped_streams()
    _configure_sdk_logging()
    try:
        return _run_script(args.script)
    finally:
        _flush_streams()
        sys.stdout, sys.stderr = saved  # in-process callers get their streams back


def _run_script(script: str) -> int:
    from armnet_runtime.lerobot.in_job import activate

    # The swap, and in a job LeRobot's calibrate/setup-motors refused when the job's own code calls them.
    activate(swap_outside_a_job=True)

    _clear_registration()  # a fresh registry per run, so in-process callers can run scripts again
    try:
        _load_user_script(script)
    except Exception:  # noqa: BLE001 - any import failure is the user's script failing
        print("armnet-runtime: failed to import user script:", file=sys.stderr)
        traceback.print_exc()
        _print_traceback_marker(_user_traceback())
        return EXIT_USER_IMPORT_FAILED

    fn = registered_main()
    if fn is None:
        print(
            f"armnet-runtime: no @main-decorated function found in {script}. "
            "Decorate exactly one function with `@main` to mark it as the entry point.",
            file=sys.stderr,
        )
        return EXIT_NO_MAIN

    try:
        ctx = build_context()
    except Exception as exc:  # noqa: BLE001 - reported, with the field named, as exit 5
        print(f"armnet-runtime: failed to build context: {exc}", file=sys.stderr)
        return EXIT_BAD_CONTEXT

    try:
        result = fn(ctx)
    except SystemExit:
        _stop_rerun(ctx)
        raise
    except Exception:  # noqa: BLE001 - user code failures become exit 1 + traceback marker
        _stop_rerun(ctx)
        print(
            f"armnet-runtime: @main function raised; job {ctx.job_id} will be marked FAILED.",
            file=sys.stderr,
        )
        traceback.print_exc()
        _print_traceback_marker(_user_traceback())
        return EXIT_USER_RAISED
    _stop_rerun(ctx)

    if result is not None:
        try:
            _print_result(result)
        except TypeError as exc:
            message = f"armnet-runtime: @main returned a value that cannot be reported: {exc}"
            print(message, file=sys.stderr)
            _print_traceback_marker(f"TypeError: {exc}\n")
            return EXIT_USER_RAISED
    return EXIT_OK


def _wind_down_quickly() -> None:
    """Leave the objects alive now out of the interpreter's last garbage collections.

    A job ends when its process exits, and its grace window counts the interpreter's shutdown:
    after a LeRobot import that shutdown took ~2.1 s here, most of it in collections walking
    torch's and LeRobot's objects (ten times that on a loaded host), and a recording job that
    had reported its end within a 3 s grace window was killed while its interpreter wound down
    (killed there, it also lost what the shutdown would have flushed). Frozen, those objects are
    skipped: the shutdown takes ~0.5 s (``bench/startup.py``).

    What a job relies on at exit still happens: atexit handlers run, and every module is kept
    alive to the end (held by ``sys``, whose globals Python clears after the modules') so that
    Python clears each module's globals itself, and what they held is finalized by reference
    counting: a module's unclosed file is flushed. A module's globals sit in a cycle with its
    functions; left to the frozen collector they would never be freed. Only other objects in
    reference cycles still alive at exit miss a last collection, which Python never promises.
    """
    sys._armnet_modules_to_clear = tuple(sys.modules.values())  # type: ignore[attr-defined]
    gc.freeze()


def main() -> None:
    """Console-script entry point: ``armnet-runtime SCRIPT``."""
    try:
        code = run()
    finally:
        _flush_streams()
        _wind_down_quickly()
    sys.exit(code)


if __name__ == "__main__":
    main()
