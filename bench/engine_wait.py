"""The container engine's CPU while a job runs: the launcher's wait against the Docker API's wait.

Podman 4.3's Docker API (Debian 12's) answers ``POST /containers/{id}/wait`` by polling
the container's state in a loop: the engine spends half a core to a core for as long
as the job runs. The container launcher (``armnet_launch.container.ContainerJob``)
blocks on a pidfd of the container's init instead and asks the engine for the exit
code only once that process has ended.

Two ways of waiting for the same held container (``sleep --hold`` seconds), alternated
``--rounds`` times in one run, each on a fresh Podman API service of the test bed:

- ``engine wait``: the Docker API's wait, what the launcher did before (the baseline);
- ``launcher``: ``ContainerJob``'s wait.

Printed: the engine's CPU seconds per second while the job runs, for each (the median
of the rounds; creating, starting and removing the container are left out: they cost
the same both ways), and their ratio (target: launcher <= 0.05x the engine wait). Usage:
``~/.cache/armnet/venv/bin/python bench/engine_wait.py [--rounds 3] [--hold 10]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from armnet_launch.container import ContainerJob
from armnet_launch.plan import ContainerSpec
from armnet_testbed.images import require_base_image
from armnet_testbed.podman import PodmanService, ulimits

TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def engine_cpu_s(service: PodmanService) -> float:
    """The Podman API service's CPU seconds so far (user + system)."""
    fields = Path(f"/proc/{service.pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS_PER_S


def engine_wait(client: Any, image: str, hold: float) -> Callable[[], None]:
    """Start a held container waited for by the Docker API's wait; the returned call ends it."""
    container = client.containers.run(image, ["sleep", str(hold)], detach=True, ulimits=ulimits(),
                                      network_mode="host")
    waiter = threading.Thread(target=container.wait, daemon=True)
    waiter.start()

    def end() -> None:
        waiter.join(hold + 60)
        container.remove(force=True)
    return end


def launcher_wait(client: Any, image: str, hold: float) -> Callable[[], None]:
    """Start a held container as the launcher does (``ContainerJob``); the returned call ends it."""
    job = ContainerJob.launch(client, ContainerSpec(image=image, env={}, command=("sleep", str(hold))))
    if not job.waits_on_pidfd:
        job.kill()
        job.remove()
        raise RuntimeError("the launcher got no pidfd of the container's init here (see the agent's log line): "
                           "it waits through the engine, so this bench would measure the engine's wait twice")

    def end() -> None:
        try:
            if job.wait(hold + 60) is None:
                raise RuntimeError("the held container did not end")
        finally:
            job.remove()
    return end


def measure(way: Callable[[Any, str, float], Callable[[], None]], hold: float) -> float:
    """The engine's CPU seconds per second while one held container runs, waited for ``way``.

    Measured from one second after the container started to one second before it ends:
    creating, starting and removing it cost the same both ways.
    """
    with PodmanService() as service:
        image = require_base_image(service.client)
        end = way(service.client, image, hold)
        try:
            time.sleep(1.0)
            before, started = engine_cpu_s(service), time.monotonic()
            time.sleep(hold - 3.0)
            return (engine_cpu_s(service) - before) / (time.monotonic() - started)
        finally:
            end()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--hold", type=float, default=10.0, help="seconds each container runs (at least 5)")
    args = parser.parse_args()
    if args.hold < 5:
        parser.error("--hold must be at least 5 s: one second at each end is left out of the measure")
    ways = {"engine wait": engine_wait, "launcher": launcher_wait}
    figures: dict[str, list[float]] = {name: [] for name in ways}
    for _ in range(args.rounds):
        for name, way in ways.items():
            figures[name].append(measure(way, args.hold))
    medians = {name: statistics.median(values) for name, values in figures.items()}
    for name, values in figures.items():
        print(f"{name:12s} engine CPU {medians[name]:.3f} s per s of the job "
              f"(rounds: {', '.join(f'{v:.3f}' for v in values)})")
    print(f"launcher / engine wait: {medians['launcher'] / medians['engine wait']:.3f}x (target <= 0.05x)")


if __name__ == "__main__":
    main()
