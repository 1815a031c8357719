"""``armnet sim``: run a simulated cell in the foreground until SIGINT or SIGTERM.

It prints one ``<arm>: <port>`` line per arm (or one JSON object with
``--json``) as soon as the ptys exist, so scripts can read the ports and point
LeRobot or the connector at them.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from pathlib import Path
from types import FrameType

from .calibration import Calibration, CalibrationError, load_calibration
from .presets import PRESETS, build_cell
from .pty_server import interleave_serving_threads


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("preset", choices=sorted(PRESETS), help="which cell to simulate")
    parser.add_argument(
        "--calibration",
        action="append",
        default=[],
        metavar="[ARM=]FILE",
        help="LeRobot calibration JSON to seed the servos with (default: the preset's shipped file). "
        "For bimanual_so101 give left=FILE and right=FILE; a bare FILE applies to every arm.",
    )
    parser.add_argument(
        "--latency-ms", type=float, default=0.0, help="delay before every reply (default 0)"
    )
    parser.add_argument(
        "--link-dir",
        type=Path,
        default=None,
        help="also publish stable symlinks <DIR>/<preset>-<arm> to the ptys",
    )
    parser.add_argument("--json", action="store_true", help="print the ports as one JSON object")


def _calibrations(preset: str, entries: list[str]) -> dict[str, Calibration]:
    arms = [a.name for a in PRESETS[preset]]
    result: dict[str, Calibration] = {}
    for entry in entries:
        arm, sep, path = entry.partition("=")
        if not sep:
            for name in arms:
                result[name] = load_calibration(entry)
            continue
        if arm not in arms:
            raise CalibrationError(
                f"--calibration {entry}: preset {preset} has arms {arms}, not {arm!r}"
            )
        result[arm] = load_calibration(path)
    return result


def run(args: argparse.Namespace) -> int:
    try:
        calibrations = _calibrations(args.preset, args.calibration)
        cell = build_cell(
            args.preset,
            calibrations=calibrations,
            latency_ms=args.latency_ms,
            link_dir=args.link_dir,
        )
    except (CalibrationError, ValueError) as exc:
        print(f"armnet sim: {exc}", file=sys.stderr)
        return 2
    interleave_serving_threads()
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        with cell:
            ports = cell.ports()
            if args.json:
                print(json.dumps({"preset": args.preset, "ports": ports}), flush=True)
            else:
                for arm, port in ports.items():
                    print(f"{arm}: {port}", flush=True)
                print("simulating; Ctrl-C to stop", file=sys.stderr, flush=True)
            while not stop.wait(0.5):
                pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
