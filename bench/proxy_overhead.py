"""Proxy overhead of a 100 Hz SO-101 control tick: through the connector vs directly.

One tick is what a LeRobot control loop does: ``sync_read("Present_Position")``
then ``sync_write("Goal_Position", ...)`` (and, with ``--camera``, one
``read_latest`` of the ``front`` camera: the newest frame, no wait). The same
simulated cell is driven, the two taking turns tick by tick (so both see the
same machine load), by:

- **direct**: the real ``FeetechMotorsBus`` (and the simulated camera) on the pty;
- **proxy**: ``RemoteFeetechMotorsBus`` / ``RemoteOpenCVCamera`` -> robot.sock ->
  the connector -> the real ``FeetechMotorsBus`` on the same pty.

The processes are those of a real cell: the simulated servos on a pty in one
process (the hardware), the connector in another (the sidecar), the bench in a
third (the job); nothing shares a GIL.

It prints per-call latency p50/p99 for both, the overhead (proxy - direct) and
the ratio, and the share of paced 100 Hz ticks that finished on time. Two floors
are timed in the same ticks: a bare ``hello`` to the connector, and a raw line
round trip between two plain processes (no armnet code), which is what any
connector in its own process pays on this machine; armnet's own share of the
overhead is printed above the latter.
Targets: overhead <= 100 us p50 and <= 500 us p99 per call; >= 99 % on time.

    ~/.cache/armnet/venv/bin/python bench/proxy_overhead.py [--ticks 500] [--rounds 2] [--camera]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

TICK_S = 0.010  # 100 Hz
WIGGLE_DEG = 1.5  # goal offset around the start pose, well inside the cell's safety limit
TARGET_P50_US, TARGET_P99_US, TARGET_ON_TIME = 100.0, 500.0, 0.99
SO101_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")


# ----------------------------------------------------------------- cell process


def serve_cell() -> None:
    """Child mode: the connector of a local so101 cell, as its own process; runs until stdin closes.

    The topology of a real cell: the simulated servos live in a third process
    (``SimulatedCellProcess``, standing in for the hardware), this process is the
    connector sidecar, and the bench's main process is the job. Nothing shares a GIL.
    """
    from armnet_agent.connector import Connector
    from armnet_agent.connector.hardware import simulated_camera_factory
    from armnet_agent.local_run.cell_spec import plan_layout, resolve_spec
    from armnet_agent.local_run.session import build_connector_config
    from armnet_agent.sim import SimulatedCellProcess
    from armnet_agent.sim.calibration import builtin_calibration, write_calibration
    from armnet_agent.sim.presets import PRESETS

    spec = resolve_spec(embodiment=None, preset="so101", task=None, grace_seconds=None)
    with tempfile.TemporaryDirectory(prefix="armnet-bench-") as run_dir:
        layout = plan_layout(spec, Path(run_dir))
        for directory in (layout.socket_dir, layout.calibration_dir):
            directory.mkdir(parents=True, exist_ok=True)
        shipped = {preset.name: preset.calibration for preset in PRESETS[spec.preset]}
        calibrations = {}
        for arm in layout.arms:
            calibrations[arm.name] = builtin_calibration(shipped[arm.name])
            write_calibration(arm.calibration_file, calibrations[arm.name])
        with SimulatedCellProcess(spec.preset, calibrations=calibrations) as sim:
            config = build_connector_config(spec, layout, sim.ports())
            with Connector(config, layout.socket_dir, camera_factory=simulated_camera_factory(source=sim)):
                arm = layout.arms[0]
                print(
                    json.dumps(
                        {
                            "port": sim.arm.port,
                            "endpoint": arm.endpoint,
                            "calibration_file": str(arm.calibration_file),
                        }
                    ),
                    flush=True,
                )
                sys.stdin.read()


# ----------------------------------------------------------------- clients


def so101_bus_kwargs(calibration_file: str) -> dict[str, Any]:
    from lerobot.motors import Motor, MotorCalibration, MotorNormMode

    raw = json.loads(Path(calibration_file).read_text())
    motors = {
        name: Motor(
            raw[name]["id"],
            "sts3215",
            MotorNormMode.RANGE_0_100 if name == "gripper" else MotorNormMode.DEGREES,
        )
        for name in SO101_JOINTS
    }
    calibration = {name: MotorCalibration(**raw[name]) for name in SO101_JOINTS}
    return {"motors": motors, "calibration": calibration}


def camera_config() -> Any:
    from lerobot.cameras.opencv import OpenCVCameraConfig

    return OpenCVCameraConfig(index_or_path="front", fps=30, width=640, height=480)


class Client:
    """One way of reaching the cell (direct or proxy), with the calls a tick makes."""

    def __init__(self, name: str, bus: Any, camera: Any | None) -> None:
        self.name = name
        self.bus = bus
        self.camera = camera
        self.bus.connect()
        if self.camera is not None:
            self.camera.connect()
        self.start = self.bus.sync_read("Present_Position")

    def close(self) -> None:
        if self.camera is not None:
            self.camera.disconnect()
        self.bus.disconnect(disable_torque=False)


def direct_client(cell: dict[str, str], with_camera: bool) -> Client:
    from armnet_agent.sim.camera import SimulatedCamera
    from lerobot.motors.feetech import FeetechMotorsBus

    camera = SimulatedCamera(camera_config()) if with_camera else None
    return Client("direct", FeetechMotorsBus(port=cell["port"], **so101_bus_kwargs(cell["calibration_file"])), camera)


def proxy_client(cell: dict[str, str], with_camera: bool) -> Client:
    os.environ["ARMNET_CELL_SOCKET"] = cell["endpoint"]
    from armnet_runtime.lerobot import RemoteFeetechMotorsBus, RemoteOpenCVCamera

    camera = RemoteOpenCVCamera(camera_config()) if with_camera else None
    bus = RemoteFeetechMotorsBus(port=cell["endpoint"], **so101_bus_kwargs(cell["calibration_file"]))
    return Client("proxy", bus, camera)


def serve_echo(path: str) -> None:
    """Child mode: the raw IPC floor, no armnet code: echo each line on a unix socket.

    The same blocking readline/sendall a connector thread does, without parsing,
    sessions or a bus: what two processes pay on this machine to hand a line over
    and back (two wake-ups). The connector's added hop can never cost less.
    """
    import socket

    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(1)
    print("ready", flush=True)
    conn, _ = listener.accept()
    reader = conn.makefile("rb")
    for line in reader:
        conn.sendall(line)


class RawEchoProbe:
    """One raw line round trip per tick to ``serve_echo``, after the same pause."""

    name = "raw"

    def __init__(self, run_dir: str) -> None:
        import socket

        path = os.path.join(run_dir, "echo.sock")
        self.process = subprocess.Popen(
            [sys.executable, __file__, "--serve-echo", path], stdout=subprocess.PIPE, text=True
        )
        assert self.process.stdout is not None
        self.process.stdout.readline()
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(path)
        self.reader = self.sock.makefile("rb")

    def round_trip(self) -> bytes:
        self.sock.sendall(b'{"op":"hello"}\n')
        return self.reader.readline()

    def close(self) -> None:
        self.reader.close()
        self.sock.close()
        self.process.wait(timeout=10)


class HelloProbe:
    """The transport floor: one ``hello`` round trip on robot.sock per tick, after the same pause."""

    name = "hello"

    def __init__(self, cell: dict[str, str]) -> None:
        from armnet_runtime.transport import PersistentConnection

        self.conn = PersistentConnection(cell["endpoint"], timeout=5.0)

    def close(self) -> None:
        self.conn.close()


# ----------------------------------------------------------------- measurement


class Samples:
    def __init__(self) -> None:
        self.calls: dict[str, list[float]] = {"sync_read": [], "sync_write": [], "camera": [], "hello": [], "raw": []}
        self.ticks = 0
        self.on_time = 0
        self.failed = 0

    def extend(self, other: Samples) -> None:
        for key, values in other.calls.items():
            self.calls[key].extend(values)
        self.ticks += other.ticks
        self.on_time += other.on_time
        self.failed += other.failed


def timed(bucket: list[float], call: Callable[[], Any]) -> Any:
    began = time.perf_counter()
    value = call()
    bucket.append(time.perf_counter() - began)
    return value


def tick_work(client: Client | HelloProbe | RawEchoProbe, tick: int, samples: Samples) -> bool:
    """One control tick's calls on ``client``; False when a bus reply was lost."""
    if isinstance(client, RawEchoProbe):
        timed(samples.calls["raw"], client.round_trip)
        return True
    if isinstance(client, HelloProbe):
        probe = client
        timed(samples.calls["hello"], lambda: probe.conn.request({"op": "hello"}))
        return True
    offset = WIGGLE_DEG * math.sin(tick / 20.0)
    goals = {name: client.start[name] + (offset if name != "gripper" else 0.0) for name in SO101_JOINTS}
    try:
        timed(samples.calls["sync_read"], lambda: client.bus.sync_read("Present_Position"))
        timed(samples.calls["sync_write"], lambda: client.bus.sync_write("Goal_Position", goals))
        camera = client.camera
        if camera is not None:
            timed(samples.calls["camera"], lambda: camera.read_latest(max_age_ms=500))
    except (ConnectionError, TimeoutError):
        # A starved simulator misses a reply now and then on a loaded machine: count it, go on.
        samples.failed += 1
        return False
    return True


def run_ticks(clients: list[Client | HelloProbe | RawEchoProbe], ticks: int) -> dict[str, Samples]:
    """Paced 100 Hz ticks, the clients taking turns tick by tick.

    Interleaving (rather than one block per client) gives both the same machine
    load, which on a shared machine drifts over seconds. A tick is on time when
    its work ends before the next tick starts.
    """
    samples = {client.name: Samples() for client in clients}
    next_tick = time.perf_counter()
    for tick in range(ticks * len(clients)):
        client = clients[tick % len(clients)]
        mine = samples[client.name]
        ok = tick_work(client, tick // len(clients), mine)
        next_tick += TICK_S
        mine.ticks += 1
        remaining = next_tick - time.perf_counter()
        if remaining >= 0 and ok:
            mine.on_time += 1
            time.sleep(remaining)
        else:
            next_tick = time.perf_counter()  # late: restart the grid instead of bursting
    return samples


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return math.nan
    index = min(len(ordered) - 1, max(0, math.ceil(q / 100.0 * len(ordered)) - 1))
    return ordered[index]


def report(direct: Samples, proxy: Samples, hello: Samples, raw: Samples, with_camera: bool) -> bool:
    print(f"ticks per mode: {direct.ticks} (100 Hz, paced)")
    print(f"{'call':<11}{'direct p50':>12}{'direct p99':>12}{'proxy p50':>12}{'proxy p99':>12}"
          f"{'ovh p50':>10}{'ovh p99':>10}{'ratio':>8}   (microseconds)")
    ok = True
    r50 = percentile(raw.calls["raw"], 50) * 1e6
    for call in ("sync_read", "sync_write") + (("camera",) if with_camera else ()):
        d50, d99 = (percentile(direct.calls[call], q) * 1e6 for q in (50, 99))
        p50, p99 = (percentile(proxy.calls[call], q) * 1e6 for q in (50, 99))
        o50, o99 = p50 - d50, p99 - d99
        print(f"{call:<11}{d50:>12.0f}{d99:>12.0f}{p50:>12.0f}{p99:>12.0f}{o50:>10.0f}{o99:>10.0f}{p50 / d50:>8.2f}")
        if call != "camera":
            ok = ok and o50 <= TARGET_P50_US and o99 <= TARGET_P99_US
    h50, h99 = (percentile(hello.calls["hello"], q) * 1e6 for q in (50, 99))
    r99 = percentile(raw.calls["raw"], 99) * 1e6
    print(f"floor: a raw line round trip between two plain processes (no armnet code), after the same pause: "
          f"{r50:.0f} us p50, {r99:.0f} us p99")
    print(f"floor: a bare 'hello' round trip on robot.sock after the same pause: {h50:.0f} us p50, {h99:.0f} us p99")
    for call in ("sync_read", "sync_write"):
        o50 = (percentile(proxy.calls[call], 50) - percentile(direct.calls[call], 50)) * 1e6
        print(f"armnet's own share of the {call} overhead (p50 overhead - raw floor p50): {o50 - r50:.0f} us")
    direct_share = direct.on_time / direct.ticks
    proxy_share = proxy.on_time / proxy.ticks
    print(f"failed ticks (bus reply lost): direct {direct.failed}, proxy {proxy.failed}")
    print(f"100 Hz ticks on time: direct {direct_share:.2%}, proxy {proxy_share:.2%} (target >= {TARGET_ON_TIME:.0%})")
    ok = ok and proxy_share >= TARGET_ON_TIME
    print(f"targets (bus calls: overhead <= {TARGET_P50_US:.0f} us p50, <= {TARGET_P99_US:.0f} us p99; "
          f"on time >= {TARGET_ON_TIME:.0%}): {'met' if ok else 'NOT met'}")
    return ok


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ticks", type=int, default=500, help="ticks per mode per round (default 500 = 5 s)")
    parser.add_argument("--rounds", type=int, default=2, help="rounds; each swaps which mode ticks first (default 2)")
    parser.add_argument("--camera", action="store_true", help="also read one camera frame per tick")
    parser.add_argument("--serve-cell", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--serve-echo", metavar="PATH", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve_cell:
        serve_cell()
        return 0
    if args.serve_echo:
        serve_echo(args.serve_echo)
        return 0
    cell_process = subprocess.Popen(
        [sys.executable, __file__, "--serve-cell"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert cell_process.stdout is not None
        cell = json.loads(cell_process.stdout.readline())
        totals = {"direct": Samples(), "proxy": Samples(), "hello": Samples(), "raw": Samples()}
        clients: list[Client | HelloProbe | RawEchoProbe] = []
        echo_dir = tempfile.TemporaryDirectory(prefix="armnet-bench-echo-")
        try:
            for make in (direct_client, proxy_client):
                clients.append(make(cell, args.camera))
            clients.append(HelloProbe(cell))
            clients.append(RawEchoProbe(echo_dir.name))
            run_ticks(clients, 20)  # warm-up: caches, first frame
            for _ in range(args.rounds):
                for name, samples in run_ticks(clients, args.ticks).items():
                    totals[name].extend(samples)
                clients.append(clients.pop(0))  # rotate: no mode always goes first
        finally:
            for client in clients:
                client.close()
            echo_dir.cleanup()
        report(totals["direct"], totals["proxy"], totals["hello"], totals["raw"], args.camera)
    finally:
        if cell_process.stdin is not None:
            cell_process.stdin.close()
        cell_process.wait(timeout=30)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
