"""Proxy overhead of a LeRobot control tick: through the connector vs directly, with targets.

One tick is what a LeRobot control loop does: ``sync_read("Present_Position")``
then ``sync_write("Goal_Position", ...)`` per arm, and, with cameras, one
``read_latest`` per camera (the newest 640x480x3 frame, no wait). The same
simulated cell is driven, the modes taking turns tick by tick (so all see the
same machine load), by:

- **direct**: the real ``FeetechMotorsBus`` (and the simulated camera) on the pty;
- **proxy**: ``RemoteFeetechMotorsBus`` / ``RemoteOpenCVCamera`` -> robot.sock ->
  the connector -> the real ``FeetechMotorsBus`` on the same pty; frames come
  through the connector's shared-memory frame area (a tmpfs, as in a pod).

The processes are those of a real cell: the simulated servos on a pty in one
process (the hardware), the connector in another (the sidecar), the proxied job
in the bench's own process, and the direct job in a process of its own, as on a
bare machine; nothing shares a GIL. Each job's cameras capture in its own
process and draw the arm as it moves, so every frame is a new picture, as a real
camera decodes a new frame every period: the connector's for the proxied job,
the direct job's own for the direct one (with the direct camera in the bench's
process, its capture thread would load the proxied job's process, which on a
real cell has none; and a camera that re-sent one still picture would cost the
direct job nothing per frame).

Modes:

- default: a 100 Hz tick of one SO-101 arm;
- ``--camera``: a 100 Hz tick of one arm and one camera;
- ``--bimanual``: a 30 Hz tick of a bimanual SO-101 (both arms) and two cameras;
- ``--record``: the connector keeps the cell's record of the job (the servo trace of every
  tick's positions, the camera's video) while the same connector without it ticks beside it as
  the baseline, in the same ticks: the ratio and the ticks on time say what the record costs;
- ``--completion region|classifier`` (with ``--camera``): the connector's completion
  monitor scores the camera at 30 Hz, its fastest rate, with that scorer (the arm on
  the target region, or the simulated cells' learned classifier) while the ticks run:
  every target then says what the monitor costs the job (it must cost nothing a
  target can see); the frames it scored are printed at the end.

Floors timed in the same ticks: a raw line round trip between two plain
processes (no armnet code: what any connector in its own process pays), a bare
``hello`` to the connector, and an in-memory copy of a 640x480x3 frame. Each
figure is printed next to its target (docs/benchmarks.md):

- bus calls: armnet's own share (proxy overhead p50 - raw floor p50) <= 50 us;
- camera ``read_latest``: proxy overhead <= 1 ms p50 and <= 2x the frame copy;
- ticks on time: >= 99 % (100 Hz one arm + one camera; 30 Hz bimanual).

``--compare-with TREE`` adds a third way in the same ticks: another checkout's whole
path (its proxy, in a client process of its own that times its calls, its connector
and its simulator), for a before/after of a change on a machine others load.

    ~/.cache/armnet/venv/bin/python bench/proxy_overhead.py [--ticks 500] [--rounds 2] [--camera | --bimanual]
        [--compare-with /path/to/other/checkout]
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

WIGGLE_DEG = 1.5  # goal offset around the start pose, well inside the cell's safety limit
TARGET_SHARE_US = 50.0  # armnet's own share of a bus call, p50
TARGET_CAMERA_US = 1000.0  # read_latest proxy overhead, p50
TARGET_COPY_RATIO = 2.0  # read_latest proxy overhead / in-memory frame copy, p50
TARGET_ON_TIME = 0.99
SO101_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
FRAME_SHAPE = (480, 640, 3)


# ----------------------------------------------------------------- cell process


def monitor_settings(scorer: str) -> Any:
    """The completion settings ``--completion`` turns on: ``scorer`` on the camera at its fastest rate."""
    from armnet_core.cell_completion import MAX_RATE_HZ, CompletionConfig
    from armnet_sim.render import target_region
    from armnet_sim.scene_samples import HEIGHT, SHIPPED_CLASSIFIER, SHIPPED_CLASSIFIER_INPUT, WIDTH

    if scorer == "classifier":
        settings: dict[str, Any] = {"classifier": {"model": str(SHIPPED_CLASSIFIER.resolve()),
                                                   "inputSize": SHIPPED_CLASSIFIER_INPUT}}
    else:
        left, top, width, height = target_region(WIDTH, HEIGHT)
        settings = {"region": {"left": left, "top": top, "width": width, "height": height},
                    "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 80}}
    return CompletionConfig.model_validate({"camera": "front", "scorer": scorer, "rateHz": MAX_RATE_HZ, **settings})


def serve_cell(preset: str, completion: str | None = None, record: bool = False) -> None:
    """Child mode: the connector of a local cell, as its own process; runs until stdin closes.

    The topology of a real cell: the simulated servos live in a third process
    (``SimulatedCellProcess``, standing in for the hardware), this process is the
    connector sidecar, and the bench's main process is the job. Nothing shares a GIL.
    The socket directory is on a tmpfs (/dev/shm), as a pod's ``emptyDir: {medium: Memory}``.
    ``record``: the connector keeps the cell's record of the job (servo trace, camera video) on disk.
    """
    from armnet_connector import Connector
    from armnet_connector.hardware import simulated_camera_factory
    from armnet_launch.cell_spec import plan_layout, resolve_spec
    from armnet_launch.sim_cell import build_connector_config
    from armnet_sim import SimulatedCellProcess
    from armnet_sim.calibration import builtin_calibration, write_calibration
    from armnet_sim.presets import PRESETS

    spec = resolve_spec(embodiment=None, preset=preset, task=None, grace_seconds=None)
    with tempfile.TemporaryDirectory(prefix="armnet-bench-", dir="/dev/shm") as run_dir, \
            tempfile.TemporaryDirectory(prefix="armnet-bench-record-") as record_dir:
        layout = plan_layout(spec, Path(run_dir))
        for directory in (layout.socket_dir, layout.calibration_dir):
            directory.mkdir(parents=True, exist_ok=True)
        shipped = {arm_preset.name: arm_preset.calibration for arm_preset in PRESETS[spec.preset]}
        calibrations = {}
        for arm in layout.arms:
            calibrations[arm.name] = builtin_calibration(shipped[arm.name])
            write_calibration(arm.calibration_file, calibrations[arm.name])
        with SimulatedCellProcess(spec.preset, calibrations=calibrations) as sim:
            ports = sim.ports()
            config = build_connector_config(spec, layout, ports)
            if completion is not None:
                config = config.model_copy(update={"completion": monitor_settings(completion)})
            with Connector(config, layout.socket_dir, camera_factory=simulated_camera_factory(source=sim),
                           record_dir=record_dir if record else None) as connector:
                arms = [
                    {"port": ports[arm.name], "endpoint": arm.endpoint, "calibration_file": str(arm.calibration_file)}
                    for arm in layout.arms
                ]
                print(json.dumps({"arms": arms, "endpoint": layout.robot_endpoint}), flush=True)
                sys.stdin.read()
                counters = connector.counters
            print(json.dumps({"scored": counters.completion_frames_scored,
                              "scorer_errors": counters.completion_scorer_errors,
                              "scorer_slow": counters.completion_scorer_slow,
                              "trace_rows": counters.trace_rows_written, "trace_dropped": counters.trace_rows_dropped,
                              "video_frames": counters.video_frames_written,
                              "video_dropped": counters.video_frames_dropped}), flush=True)


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

    def __init__(self, name: str, buses: list[Any], cameras: list[Any]) -> None:
        self.name = name
        self.buses = buses
        self.cameras = cameras
        #: Arm name -> the goals last sent, for cameras that draw them (the direct job's; None: nobody draws).
        self.poses: dict[str, dict[str, float]] | None = None
        for bus in buses:
            connect_with_retries(bus)
        for camera in cameras:
            camera.connect()
        self.starts = [bus.sync_read("Present_Position") for bus in buses]

    def close(self) -> None:
        for camera in self.cameras:
            camera.disconnect()
        for bus in self.buses:
            bus.disconnect(disable_torque=False)


def connect_with_retries(bus: Any, attempts: int = 3) -> None:
    """``bus.connect()``; a starved simulator can miss the handshake on a loaded machine: try again."""
    for attempt in range(attempts):
        try:
            bus.connect()
            return
        except (ConnectionError, RuntimeError):  # RuntimeError: LeRobot's handshake found servos missing
            if attempt == attempts - 1:
                raise
            if bus.is_connected:  # a failed handshake leaves the port open
                bus.disconnect(disable_torque=False)
            time.sleep(0.2)


def direct_client(cell: dict[str, Any], arms: int, cameras: int) -> Client:
    """The bare machine's way: LeRobot's bus on the pty, and cameras drawing the arm the ticks move."""
    from armnet_sim.camera import SimulatedCamera
    from lerobot.motors.feetech import FeetechMotorsBus

    buses = [FeetechMotorsBus(port=arm["port"], **so101_bus_kwargs(arm["calibration_file"])) for arm in cell["arms"][:arms]]
    poses: dict[str, dict[str, float]] = {}
    client = Client("direct", buses, [SimulatedCamera(camera_config(), source=lambda: dict(poses))
                                      for _ in range(cameras)])
    client.poses = poses
    return client


def proxy_client(cell: dict[str, Any], arms: int, cameras: int) -> Client:
    os.environ["ARMNET_CELL_SOCKET"] = cell["endpoint"]
    from armnet_runtime.lerobot import RemoteFeetechMotorsBus, RemoteOpenCVCamera

    buses = [
        RemoteFeetechMotorsBus(port=arm["endpoint"], **so101_bus_kwargs(arm["calibration_file"]))
        for arm in cell["arms"][:arms]
    ]
    return Client("proxy", buses, [RemoteOpenCVCamera(camera_config()) for _ in range(cameras)])


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

    def work(self, samples: Samples) -> None:
        def round_trip() -> bytes:
            self.sock.sendall(b'{"op":"hello"}\n')
            return self.reader.readline()

        timed(samples.calls["raw"], round_trip)

    def close(self) -> None:
        self.reader.close()
        self.sock.close()
        self.process.wait(timeout=10)


class HelloProbe:
    """The transport floor: one ``hello`` round trip on robot.sock per tick, after the same pause."""

    name = "hello"

    def __init__(self, cell: dict[str, Any]) -> None:
        from armnet_runtime.transport import PersistentConnection

        self.conn = PersistentConnection(cell["endpoint"], timeout=5.0)

    def work(self, samples: Samples) -> None:
        timed(samples.calls["hello"], lambda: self.conn.request({"op": "hello"}))

    def close(self) -> None:
        self.conn.close()


def serve_client(cell_line: str, arms: int, cameras: int, way: str) -> None:
    """Child mode: one job's calls in a process of its own, run on the tick the parent asks for.

    ``way`` is ``direct`` (the bare machine's job) or ``proxy`` (``--compare-with``: started with
    the other checkout's ``PYTHONPATH``, so ``armnet_runtime`` is that tree's). Reads a tick
    number per line; answers with the call times (or a lost reply).
    """
    make = direct_client if way == "direct" else proxy_client
    client = make(json.loads(cell_line), arms, cameras)
    print("ready", flush=True)
    for line in sys.stdin:
        samples = Samples()
        ok = tick_work(client, int(line), samples)
        print(json.dumps({"ok": ok, "calls": {k: v for k, v in samples.calls.items() if v}}), flush=True)
    client.close()


class ClientProcessProbe:
    """A job in its own process (``serve_client``): one tick of its calls per tick, timed there.

    ``direct``: the bare machine's job; ``baseline``: another checkout's proxy (``--compare-with``).
    """

    def __init__(self, name: str, cell_line: str, arms: int, cameras: int = 0, tree: Path | None = None) -> None:
        self.name = name
        way = "direct" if name == "direct" else "proxy"
        self.process = subprocess.Popen(
            [sys.executable, __file__, "--serve-client", str(arms), "--client-cameras", str(cameras),
             "--client-way", way],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            env=tree_env(tree) if tree is not None else None,
        )
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(cell_line)
        self.process.stdin.flush()
        if self.process.stdout.readline().strip() != "ready":
            raise RuntimeError(f"the {self.name} client did not start")

    def work(self, samples: Samples, tick: int) -> bool:
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(f"{tick}\n")
        self.process.stdin.flush()
        answer = json.loads(self.process.stdout.readline())
        for key, values in answer["calls"].items():
            samples.calls[key].extend(values)
        if not answer["ok"]:
            samples.failed += 1
        return bool(answer["ok"])

    def close(self) -> None:
        if self.process.stdin is not None:
            self.process.stdin.close()
        self.process.wait(timeout=30)


class CopyProbe:
    """The memory floor: an in-memory copy of a 640x480x3 frame per tick, after the same pause."""

    name = "copy"

    def __init__(self) -> None:
        import numpy as np

        self.frame = np.random.default_rng(0).integers(0, 256, FRAME_SHAPE, dtype=np.uint8)

    def work(self, samples: Samples) -> None:
        timed(samples.calls["copy"], self.frame.copy)

    def close(self) -> None:
        pass


# ----------------------------------------------------------------- measurement


class Samples:
    def __init__(self) -> None:
        self.calls: dict[str, list[float]] = {
            "sync_read": [], "sync_write": [], "camera": [], "hello": [], "raw": [], "copy": [],
        }
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


Probe = Client | HelloProbe | RawEchoProbe | CopyProbe | ClientProcessProbe


def tick_work(client: Probe, tick: int, samples: Samples) -> bool:
    """One control tick's calls on ``client``; False when a bus reply was lost."""
    if isinstance(client, ClientProcessProbe):
        return client.work(samples, tick)
    if not isinstance(client, Client):
        client.work(samples)
        return True
    offset = WIGGLE_DEG * math.sin(tick / 20.0)
    try:
        for arm, (bus, start) in enumerate(zip(client.buses, client.starts, strict=True)):
            goals = {name: start[name] + (offset if name != "gripper" else 0.0) for name in SO101_JOINTS}
            if client.poses is not None:
                client.poses[f"arm{arm}"] = goals
            timed(samples.calls["sync_read"], lambda bus=bus: bus.sync_read("Present_Position"))
            timed(samples.calls["sync_write"], lambda bus=bus, goals=goals: bus.sync_write("Goal_Position", goals))
        for camera in client.cameras:
            timed(samples.calls["camera"], lambda camera=camera: camera.read_latest(max_age_ms=500))
    except (ConnectionError, TimeoutError):
        # A starved simulator misses a reply now and then on a loaded machine: count it, go on.
        samples.failed += 1
        return False
    return True


def run_ticks(clients: list[Probe], ticks: int, period_s: float) -> dict[str, Samples]:
    """Paced ticks, the clients taking turns tick by tick.

    Interleaving (rather than one block per client) gives all the same machine
    load, which on a shared machine drifts over seconds. A tick is on time when
    its work ends before the next tick starts.
    """
    samples = {client.name: Samples() for client in clients}
    next_tick = time.perf_counter()
    for tick in range(ticks * len(clients)):
        client = clients[tick % len(clients)]
        mine = samples[client.name]
        ok = tick_work(client, tick // len(clients), mine)
        next_tick += period_s
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


def us(values: list[float], q: float) -> float:
    return percentile(values, q) * 1e6


def verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def report_baseline(totals: dict[str, Samples], raw_p50: float, label: str, cameras: int) -> None:
    """``--compare-with``/``--record``: the same calls through the baseline's proxy and connector, in the same ticks."""
    direct, proxy, baseline = totals["direct"], totals["proxy"], totals.get("baseline")
    if baseline is None or not baseline.ticks:
        return
    for call in ("sync_read", "sync_write") + (("camera",) if cameras else ()):
        d50 = us(direct.calls[call], 50)
        b50, p50 = us(baseline.calls[call], 50), us(proxy.calls[call], 50)
        print(f"{call}: {label}: p50 {b50:.0f} us (share {b50 - d50 - raw_p50:.0f} us), "
              f"this one {p50:.0f} us (share {p50 - d50 - raw_p50:.0f} us): ratio {p50 / b50:.2f}, "
              f"this one saves {b50 - p50:.0f} us")
    print(f"ticks on time: {label} {baseline.on_time / baseline.ticks:.2%}, "
          f"this one {proxy.on_time / proxy.ticks:.2%}")


def report(totals: dict[str, Samples], *, cameras: int, hz: float, baseline: str) -> bool:
    direct, proxy = totals["direct"], totals["proxy"]
    raw, hello, copy = totals["raw"].calls["raw"], totals["hello"].calls["hello"], totals["copy"].calls["copy"]
    print(f"ticks per mode: {direct.ticks} ({hz:g} Hz, paced)")
    print(f"{'call':<11}{'direct p50':>12}{'direct p99':>12}{'proxy p50':>12}{'proxy p99':>12}"
          f"{'ovh p50':>10}{'ovh p99':>10}{'ratio':>8}   (microseconds)")
    calls = ("sync_read", "sync_write") + (("camera",) if cameras else ())
    for call in calls:
        d50, d99 = us(direct.calls[call], 50), us(direct.calls[call], 99)
        p50, p99 = us(proxy.calls[call], 50), us(proxy.calls[call], 99)
        print(f"{call:<11}{d50:>12.0f}{d99:>12.0f}{p50:>12.0f}{p99:>12.0f}{p50 - d50:>10.0f}{p99 - d99:>10.0f}"
              f"{p50 / d50:>8.2f}")
    r50 = us(raw, 50)
    print(f"floor: a raw line round trip between two plain processes (no armnet code), after the same pause: "
          f"{r50:.0f} us p50, {us(raw, 99):.0f} us p99")
    print(f"floor: a bare 'hello' round trip on robot.sock after the same pause: {us(hello, 50):.0f} us p50, "
          f"{us(hello, 99):.0f} us p99")
    ok = True
    for call in ("sync_read", "sync_write"):
        share = us(proxy.calls[call], 50) - us(direct.calls[call], 50) - r50
        ok = ok and share <= TARGET_SHARE_US
        print(f"{call}: armnet's own share (p50 overhead - raw floor p50): {share:.0f} us "
              f"(target <= {TARGET_SHARE_US:.0f} us: {verdict(share <= TARGET_SHARE_US)})")
    if cameras:
        c50 = us(copy, 50)
        overhead = us(proxy.calls["camera"], 50) - us(direct.calls["camera"], 50)
        print(f"floor: an in-memory copy of a 640x480x3 frame after the same pause: {c50:.0f} us p50, "
              f"{us(copy, 99):.0f} us p99")
        camera_ok = overhead <= TARGET_CAMERA_US and overhead <= TARGET_COPY_RATIO * c50
        ok = ok and camera_ok
        print(f"camera read_latest: proxy overhead {overhead:.0f} us p50 = {overhead / c50:.2f}x the frame copy "
              f"(target <= {TARGET_CAMERA_US:.0f} us and <= {TARGET_COPY_RATIO:g}x: {verdict(camera_ok)})")
    report_baseline(totals, r50, baseline, cameras)
    print(f"failed ticks (bus reply lost): direct {direct.failed}, proxy {proxy.failed}")
    direct_share, proxy_share = direct.on_time / direct.ticks, proxy.on_time / proxy.ticks
    ok = ok and proxy_share >= TARGET_ON_TIME
    print(f"{hz:g} Hz ticks on time: direct {direct_share:.2%}, proxy {proxy_share:.2%} "
          f"(target >= {TARGET_ON_TIME:.0%}: {verdict(proxy_share >= TARGET_ON_TIME)})")
    print(f"all targets: {verdict(ok)}")
    return ok


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ticks", type=int, default=500, help="ticks per mode per round (default 500)")
    parser.add_argument("--rounds", type=int, default=2, help="rounds; each swaps which mode ticks first (default 2)")
    shape = parser.add_mutually_exclusive_group()
    shape.add_argument("--camera", action="store_true", help="100 Hz: one arm and one camera")
    shape.add_argument("--bimanual", action="store_true", help="30 Hz: a bimanual SO-101 and two cameras")
    parser.add_argument(
        "--compare-with", metavar="TREE", type=Path,
        help="also tick a proxy to a connector run from another checkout (say the code before a change), "
             "in the same ticks: a before/after on a shared machine",
    )
    parser.add_argument("--completion", choices=("region", "classifier"),
                        help="with --camera: the connector's completion monitor scores the camera at 30 Hz meanwhile")
    parser.add_argument("--record", action="store_true",
                        help="the connector keeps the cell's record of the job (servo trace, camera video); the "
                             "same connector without it ticks beside it, in the same ticks, as the baseline")
    parser.add_argument("--serve-cell", metavar="PRESET", help=argparse.SUPPRESS)
    parser.add_argument("--serve-echo", metavar="PATH", help=argparse.SUPPRESS)
    parser.add_argument("--serve-client", metavar="ARMS", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--client-cameras", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--client-way", choices=("direct", "proxy"), default="proxy", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve_client:
        serve_client(sys.stdin.readline(), args.serve_client, args.client_cameras, args.client_way)
        return 0
    if args.serve_cell:
        serve_cell(args.serve_cell, args.completion, args.record)
        return 0
    if args.record and args.compare_with:
        parser.error("--record brings its own baseline (this tree without the record): leave out --compare-with")
    if args.completion and not args.camera:
        parser.error("--completion needs --camera: the monitor scores the cell's one camera")
    if args.serve_echo:
        serve_echo(args.serve_echo)
        return 0
    preset, arms, cameras, hz = ("bimanual_so101", 2, 2, 30.0) if args.bimanual else ("so101", 1, int(args.camera), 100.0)
    cell_process = subprocess.Popen(
        [sys.executable, __file__, "--serve-cell", preset, *(["--completion", args.completion] if args.completion else []),
         *(["--record"] if args.record else [])],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    baseline_tree = Path(__file__).resolve().parent.parent if args.record else args.compare_with
    baseline_process = serve_baseline(baseline_tree, preset) if baseline_tree else None
    try:
        assert cell_process.stdout is not None
        cell_line = cell_process.stdout.readline()
        cell = json.loads(cell_line)
        totals = {name: Samples() for name in ("direct", "proxy", "hello", "raw", "copy", "baseline")}
        clients: list[Probe] = []
        echo_dir = tempfile.TemporaryDirectory(prefix="armnet-bench-echo-")
        try:
            clients.append(ClientProcessProbe("direct", cell_line, arms, cameras))
            clients.append(proxy_client(cell, arms, cameras))
            if baseline_process is not None:
                assert baseline_process.stdout is not None and baseline_tree is not None
                clients.append(ClientProcessProbe("baseline", baseline_process.stdout.readline(), arms,
                                                  cameras if args.record else 0, tree=baseline_tree))
            clients += [HelloProbe(cell), RawEchoProbe(echo_dir.name), CopyProbe()]
            run_ticks(clients, 20, 1.0 / hz)  # warm-up: caches, first frames
            for _ in range(args.rounds):
                for name, samples in run_ticks(clients, args.ticks, 1.0 / hz).items():
                    totals[name].extend(samples)
                clients.append(clients.pop(0))  # rotate: no mode always goes first
        finally:
            for client in clients:
                client.close()
            echo_dir.cleanup()
        report(totals, cameras=cameras, hz=hz,
               baseline="the same connector without the record" if args.record else "the baseline tree's proxy")
    finally:
        for process in (cell_process, baseline_process):
            if process is not None and process.stdin is not None:
                process.stdin.close()
                process.wait(timeout=30)
    final = json.loads(cell_process.stdout.readline() or "{}") if cell_process.stdout is not None else {}
    if args.record:
        print(f"the cell's record meanwhile: {final.get('trace_rows')} servo trace rows kept "
              f"({final.get('trace_dropped')} dropped), {final.get('video_frames')} video frames kept "
              f"({final.get('video_dropped')} dropped)")
    if args.completion:
        print(f"completion monitor ({args.completion}, 30 Hz) meanwhile: {final.get('scored')} frames scored, "
              f"{final.get('scorer_errors')} scorer errors, {final.get('scorer_slow')} slow scores")
    return 0


def tree_env(tree: Path) -> dict[str, str]:
    """The environment that imports armnet from another checkout."""
    tree = tree.resolve()
    paths = [tree / "runtime" / "src", tree / "agent", tree / "operator", tree / "cli", tree]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(str(path) for path in paths)}


def serve_baseline(tree: Path, preset: str) -> subprocess.Popen[str]:
    """The cell of another checkout (its own simulator and connector), for ``--compare-with``; of this
    one, without the record, for ``--record``."""
    return subprocess.Popen(
        [sys.executable, str(tree.resolve() / "bench" / "proxy_overhead.py"), "--serve-cell", preset],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=tree_env(tree),
    )


if __name__ == "__main__":
    raise SystemExit(main())
