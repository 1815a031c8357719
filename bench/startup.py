"""A job's start-up: from the process's start to the job's first line, against plain Python.

What the platform adds before ``@main`` (the SDK's import, the LeRobot import swap, the
context) must cost next to nothing: a job that does not import LeRobot starts like a
plain Python process that imports the SDK, and a job that imports LeRobot pays LeRobot's
own import and little more (the swap happens when the job imports LeRobot, through an
import hook, not before ``@main``).

Four commands, alternated ``--rounds`` times in one run (the median of each is printed):

- ``sdk``: ``python -c "import armnet_runtime; print(...)"`` (the baseline of a job that
  does not import LeRobot);
- ``hello job``: ``armnet-runtime`` running a job that prints in ``@main`` and imports
  nothing else (target: <= 1.5x ``sdk``);
- ``lerobot``: ``python -c "import lerobot.motors.feetech, lerobot.cameras.opencv; ..."``
  (the baseline of a job that uses LeRobot);
- ``lerobot job``: ``armnet-runtime`` running a job that imports the same modules at its
  top and prints in ``@main`` (target: <= 1.2x ``lerobot``).

Its end is measured too, from that first line to the process's exit: the job's grace
window counts its interpreter's shutdown, which after a LeRobot import is seconds of
garbage collection unless the runtime skips it (``armnet_runtime.cli._wind_down_quickly``;
target: the ``lerobot job``'s wind-down <= 0.6x ``lerobot``'s, both print their line and
end).

Each start is measured to the first line on the child's stdout, in the same environment a
job has (the ``ARMNET_*`` variables of a local run, no connector needed: nothing here
opens a device). Usage: ``~/.cache/armnet/venv/bin/python bench/startup.py [--rounds 7]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HELLO_JOB = """
from armnet_runtime import main

@main
def run(ctx):
    print("first line", flush=True)
"""

LEROBOT_JOB = """
import lerobot.cameras.opencv
import lerobot.motors.feetech
from armnet_runtime import main

@main
def run(ctx):
    print("first line", flush=True)
"""

JOB_ENV = {
    "ARMNET_JOB_ID": "bench-startup",
    "ARMNET_EMBODIMENT": "lerobot/so-101",
    "ARMNET_TASK": "bench",
    "ARMNET_TIMEOUT_SECONDS": "60",
    "ARMNET_CELL_CONFIG": '{"camera_configs": {"front": {"index_or_path": 0, "fps": 30}}}',
}


def time_to_first_line(argv: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Seconds from spawning ``argv`` to the first line it writes on stdout, and from that line to its exit."""
    started = time.perf_counter()
    child = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env)
    assert child.stdout is not None
    line = child.stdout.readline()
    first_line = time.perf_counter()
    child.stdout.read()
    code = child.wait()
    if not line or code != 0:
        raise SystemExit(f"{' '.join(argv)} exited {code} before its first line")
    return first_line - started, time.perf_counter() - first_line


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7, help="alternations of the four commands")
    args = parser.parse_args()
    python = sys.executable
    runtime = str(Path(python).with_name("armnet-runtime"))
    env = {**os.environ, **JOB_ENV}
    with tempfile.TemporaryDirectory(prefix="armnet-bench-startup-") as tmp:
        hello = Path(tmp) / "hello_job.py"
        hello.write_text(HELLO_JOB)
        lerobot_job = Path(tmp) / "lerobot_job.py"
        lerobot_job.write_text(LEROBOT_JOB)
        commands = {
            "sdk": [python, "-c", "import armnet_runtime; print('first line', flush=True)"],
            "hello job": [runtime, str(hello)],
            "lerobot": [python, "-c", "import lerobot.motors.feetech, lerobot.cameras.opencv; "
                        "print('first line', flush=True)"],
            "lerobot job": [runtime, str(lerobot_job)],
        }
        for argv in commands.values():  # warm the page cache once; not counted
            time_to_first_line(argv, env)
        samples: dict[str, list[float]] = {name: [] for name in commands}
        ends: dict[str, list[float]] = {name: [] for name in commands}
        for _ in range(args.rounds):
            for name, argv in commands.items():
                start, end = time_to_first_line(argv, env)
                samples[name].append(start)
                ends[name].append(end)
    median = {name: statistics.median(values) for name, values in samples.items()}
    wind_down = {name: statistics.median(values) for name, values in ends.items()}
    print(f"{'command':<12} {'median s':>9} {'min s':>7} {'max s':>7} {'end s':>7}  ({args.rounds} rounds)")
    for name, values in samples.items():
        print(f"{name:<12} {median[name]:>9.3f} {min(values):>7.3f} {max(values):>7.3f} {wind_down[name]:>7.3f}")
    checks = [
        ("hello job / sdk", median["hello job"] / median["sdk"], 1.5),
        ("lerobot job / lerobot", median["lerobot job"] / median["lerobot"], 1.2),
        ("lerobot job's end / lerobot's", wind_down["lerobot job"] / wind_down["lerobot"], 0.6),
    ]
    for label, ratio, target in checks:
        print(f"{label + ':':<32} {ratio:.2f}x (target <= {target}x) {'ok' if ratio <= target else 'MISSED'}")
    return 0 if all(ratio <= target for _, ratio, target in checks) else 1


if __name__ == "__main__":
    raise SystemExit(main())
