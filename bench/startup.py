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

Each time is measured to the first line on the child's stdout, in the same environment a
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


def time_to_first_line(argv: list[str], env: dict[str, str]) -> float:
    """Seconds from spawning ``argv`` to the first line it writes on stdout."""
    started = time.perf_counter()
    child = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env)
    assert child.stdout is not None
    line = child.stdout.readline()
    elapsed = time.perf_counter() - started
    child.stdout.read()
    code = child.wait()
    if not line or code != 0:
        raise SystemExit(f"{' '.join(argv)} exited {code} before its first line")
    return elapsed


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
        for _ in range(args.rounds):
            for name, argv in commands.items():
                samples[name].append(time_to_first_line(argv, env))
    median = {name: statistics.median(values) for name, values in samples.items()}
    print(f"{'command':<12} {'median s':>9} {'min s':>7} {'max s':>7}  ({args.rounds} rounds)")
    for name, values in samples.items():
        print(f"{name:<12} {median[name]:>9.3f} {min(values):>7.3f} {max(values):>7.3f}")
    hello_ratio = median["hello job"] / median["sdk"]
    lerobot_ratio = median["lerobot job"] / median["lerobot"]
    print(f"hello job / sdk:         {hello_ratio:.2f}x (target <= 1.5x) "
          f"{'ok' if hello_ratio <= 1.5 else 'MISSED'}")
    print(f"lerobot job / lerobot:   {lerobot_ratio:.2f}x (target <= 1.2x) "
          f"{'ok' if lerobot_ratio <= 1.2 else 'MISSED'}")
    return 0 if hello_ratio <= 1.5 and lerobot_ratio <= 1.2 else 1


if __name__ == "__main__":
    raise SystemExit(main())
