"""Where armnet's share of a bus call goes: the connector's handling, stage by stage, in one process.

``proxy_overhead.py`` measures the whole hop (proxy -> socket -> connector ->
bus -> reply) against a raw line round trip. This tool opens the hop up: it
drives a real connector's ``RobotSession`` directly (no socket) with the
requests a proxied SO-101 control loop sends, and times, per call, in the same
loop and on the same pty:

- ``direct``: the real ``FeetechMotorsBus`` call (what the job pays on a bare arm);
- ``client``: the proxy's side, without the socket (encode the arguments, the
  request line, parse the reply line, decode the value);
- ``server``: the connector's side (parse the line, ``Session.handle``, which runs
  the allow-list plan, the motion guard, the policed bus and the real call,
  encode the reply line);
- ``server - direct``: armnet's own work in the connector;
- the same in CPU time (``time.thread_time``): on a machine other jobs load, the
  wall clock of one call swings by the scheduler's whims, its CPU time much less
  (for ``sync_write``; a ``sync_read``'s CPU time includes LeRobot polling the port
  for the servos' reply, so it follows the simulator's speed).

``--hot`` adds each piece of armnet's own work timed alone in a tight loop (warm
caches, no bus I/O, the minimum of 7 batches): the CPU floor of each piece, stable
enough on a loaded machine to compare two versions of one piece. A paced control
loop pays several times these (its caches are cold at every call). It also counts
the Python calls and bytecodes one ``sync_write`` / ``sync_read`` executes in the
connector (``sys.settrace``), armnet's code apart from LeRobot's, and those the proxy
executes (its requests answered in-process by the same session): deterministic.

``--profile`` adds a cProfile of the connector's handling (cumulative time,
the functions that cost the most). The simulated servos live in their own
process, as in ``proxy_overhead.py``.

    ~/.cache/armnet/venv/bin/python bench/bus_profile.py [--calls 2000] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

PAUSE_S = 0.002

from proxy_overhead import (  # noqa: E402
    SO101_JOINTS,
    WIGGLE_DEG,
    connect_with_retries,
    percentile,
    so101_bus_kwargs,
)


def _timed(bucket: list[float], cpu: list[float], call: Callable[[], Any]) -> Any:
    began, began_cpu = time.perf_counter(), time.thread_time()
    value = call()
    bucket.append(time.perf_counter() - began)
    cpu.append(time.thread_time() - began_cpu)
    return value


#: Stages that do not nest in one another (the register policy runs inside LeRobot's call).
TOP_STAGES = ("decode arguments", "motion guard", "LeRobot call (incl. register policy)")


def instrument_stages(current: dict[str, float]) -> Callable[[], None]:
    """Wrap the connector's stages so each adds its CPU time to ``current`` (signatures kept).

    Returns the undo: ``--hot`` times the pieces unwrapped (a wrapper costs ~1-2 us a call).
    """
    import functools

    from armnet_connector import motion, session
    from armnet_connector.policed_bus import BusPolicy
    from lerobot.motors.feetech import FeetechMotorsBus

    originals: list[tuple[Any, str, Any]] = []

    def wrap(owner: Any, name: str, stage: str) -> None:
        original = getattr(owner, name)
        originals.append((owner, name, original))

        @functools.wraps(original)
        def timed(*args: Any, **kwargs: Any) -> Any:
            began = time.thread_time()
            try:
                return original(*args, **kwargs)
            finally:
                current[stage] = current.get(stage, 0.0) + time.thread_time() - began

        setattr(owner, name, timed)

    wrap(session, "_arguments", "decode arguments")
    wrap(motion.MotionGuard, "check", "motion guard")
    wrap(BusPolicy, "check_all", "register policy (inside the LeRobot call)")
    for method in ("sync_write", "sync_read"):
        wrap(FeetechMotorsBus, method, "LeRobot call (incl. register policy)")

    def undo() -> None:
        for owner, name, original in reversed(originals):
            setattr(owner, name, original)

    return undo


HOT_BATCHES = 7


def hot_cpu_us(call: Callable[[], Any], calls: int) -> float:
    """CPU microseconds per call of ``call`` in a tight loop: the minimum over ``HOT_BATCHES`` batches."""
    call()
    best = math.inf
    for _ in range(HOT_BATCHES):
        began = time.thread_time()
        for _ in range(calls):
            call()
        best = min(best, (time.thread_time() - began) / calls)
    return best * 1e6


def traced_work(call: Callable[[], Any]) -> dict[str, tuple[int, int]]:
    """Python calls and bytecodes one ``call`` executes, armnet's code apart from the rest (LeRobot, serial).

    Deterministic: the same request on the same code executes the same bytecodes
    whatever the machine's load (a read's polling loop in LeRobot excepted), so a
    change to the hot path can be measured where the wall clock cannot resolve it.
    """
    counts = {"armnet": [0, 0], "LeRobot and below": [0, 0]}

    def kind(frame: Any) -> list[int]:
        name = frame.f_code.co_filename
        return counts["armnet" if "/armnet_connector/" in name or "/armnet_sim/" in name or "/armnet_runtime/" in name else "LeRobot and below"]

    _count_traced(call, kind)
    return {name: (calls, opcodes) for name, (calls, opcodes) in counts.items()}


def _count_traced(call: Callable[[], Any], counter: Callable[[Any], list[int] | None]) -> None:
    """Run ``call`` once under a trace: each frame's calls and bytecodes go to ``counter(frame)`` (None: not counted)."""

    def trace(frame: Any, event: str, _arg: Any) -> Any:
        tally = counter(frame)
        if tally is None:
            return None
        if event == "call":
            frame.f_trace_opcodes = True
            tally[0] += 1
        elif event == "opcode":
            tally[1] += 1
        return trace

    sys.settrace(trace)
    try:
        call()
    finally:
        sys.settrace(None)


class InProcessSocket:
    """Stands in for robot.sock under a proxy: each request line goes to ``session`` in this thread.

    ``serving`` is set while the connector's side runs, so a trace can leave that work out
    and count the proxy's own alone.
    """

    def __init__(self, session: Any) -> None:
        self.session = session
        self.reply = b""
        self.serving = False

    def settimeout(self, _timeout: float | None) -> None:
        pass

    def sendall(self, line: bytes) -> None:
        from armnet_connector.server import encode_reply, parse_request

        self.serving = True
        try:
            self.reply = encode_reply(self.session.handle(parse_request(line)))
        finally:
            self.serving = False

    def recv(self, _size: int) -> bytes:
        reply, self.reply = self.reply, b""
        return reply

    def close(self) -> None:
        pass


def traced_proxy_work(call: Callable[[], Any], fake: InProcessSocket) -> tuple[int, int]:
    """Python calls and bytecodes the proxy (armnet_runtime) executes for one ``call``, the connector's side left out."""
    counts = [0, 0]
    _count_traced(call, lambda frame: None if fake.serving or "/armnet_runtime/" not in frame.f_code.co_filename
                  else counts)
    return counts[0], counts[1]


def proxy_on_session(session: Any, object_id: str, endpoint: str, bus_kwargs: dict[str, Any]) -> tuple[Any, Any]:
    """A ``RemoteFeetechMotorsBus`` whose requests reach ``session``'s ``object_id`` through an ``InProcessSocket``."""
    from armnet_runtime.lerobot import RemoteFeetechMotorsBus

    proxy = RemoteFeetechMotorsBus(port=endpoint, **bus_kwargs)  # created on the real socket, then rerouted
    fake = InProcessSocket(session)
    proxy._conn.close()
    proxy._conn._sock = fake
    proxy._conn._sock_timeout = proxy._conn._timeout
    object.__setattr__(proxy, "_object_id", object_id)
    return proxy, fake


def hot_pieces(session: Any, object_id: str, goals: dict[str, float], present: dict[str, float],
               calls: int, proxy: tuple[Any, Any] | None = None) -> dict[str, Any]:
    """The connector's and the proxy's own pieces of one ``sync_read`` / ``sync_write``, each alone."""
    from armnet_connector.server import encode_reply, parse_request
    from armnet_connector.session import _arguments
    from armnet_runtime.lerobot.remote_object import encode_args
    from armnet_runtime.wire import decode, dumps_line, encode, loads_json

    handle = session.objects[object_id]
    guard = session.cell.guard
    # The goal check reuses the positions of this tick's read (presentPositionMaxAgeMs): keep them fresh.
    handle.present[True] = (math.inf, dict(present))
    write_args: list[Any] = ["Goal_Position", goals]
    write_line = dumps_line({"op": "call", "method": "sync_write", "args": encode_args(("Goal_Position", goals)),
                             "kwargs": encode({}), "object_id": object_id})
    read_reply = {"ok": True, "value": encode(present)}
    read_reply_line = encode_reply(read_reply)
    request = parse_request(write_line)
    pieces = {
        "proxy: encode a sync_write request line": lambda: dumps_line(
            {"op": "call", "method": "sync_write", "args": encode_args(("Goal_Position", goals)),
             "kwargs": encode({}), "object_id": object_id}),
        "proxy: decode a sync_read reply line": lambda: decode(loads_json(read_reply_line).get("value")),
        "connector: parse a sync_write request line": lambda: parse_request(write_line),
        "connector: decode its arguments": lambda: _arguments(request),
        "connector: motion guard, sync_write (6 goals)": lambda: guard.check(handle, "sync_write", write_args, {}),
        "connector: motion guard, sync_read": lambda: guard.check(handle, "sync_read", ["Present_Position"], {}),
        "connector: keep a sync_read's positions": lambda: guard.remember_present(
            handle, ["Present_Position"], {}, present),
        "connector: encode a sync_read reply line": lambda: encode_reply({"ok": True, "value": encode(present)}),
        "connector: encode a sync_write reply line": lambda: encode_reply({"ok": True, "value": None}),
    }
    read_line = dumps_line({"op": "call", "method": "sync_read", "args": encode_args(("Present_Position",)),
                            "kwargs": encode({}), "object_id": object_id})
    try:
        timed = {name: hot_cpu_us(call, calls) for name, call in pieces.items()}
        for method, line in (("sync_write", write_line), ("sync_read", read_line)):
            time.sleep(PAUSE_S)
            # This tick's read, as in a control loop: the write's goal check reuses its positions
            # (the timed pieces above took longer than presentPositionMaxAgeMs).
            session.handle(parse_request(read_line))
            work = traced_work(lambda line=line: encode_reply(session.handle(parse_request(line))))
            for part, (n_calls, opcodes) in work.items():
                timed[f"work: {method}, {part} (Python calls / bytecodes)"] = (n_calls, opcodes)
        if proxy is not None:
            bus, fake = proxy
            for method, call in (("sync_write", lambda: bus.sync_write("Goal_Position", goals)),
                                 ("sync_read", lambda: bus.sync_read("Present_Position"))):
                call()  # the proxy's first call of a method asks whether it is one
                time.sleep(PAUSE_S)
                timed[f"work: {method}, the proxy's side (Python calls / bytecodes)"] = traced_proxy_work(call, fake)
        return timed
    finally:
        handle.present.clear()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=2000, help="ticks (one sync_read + one sync_write each)")
    parser.add_argument("--profile", action="store_true", help="cProfile the connector's handling")
    parser.add_argument("--sort", default="tottime", help="cProfile sort key (tottime, cumulative, ...)")
    parser.add_argument("--top", type=int, default=30, help="functions listed")
    parser.add_argument("--hot", action="store_true",
                        help="each piece of armnet's own work alone in a tight loop (warm caches, no bus I/O)")
    parser.add_argument("--hot-calls", type=int, default=3000, help="calls per batch of --hot")
    parser.add_argument("--stages", action="store_true",
                        help="CPU time of each stage of the connector's handling (wrappers add ~1 us each)")
    args = parser.parse_args()

    from armnet_connector import Connector
    from armnet_connector.server import encode_reply, parse_request
    from armnet_connector.session import RobotSession
    from armnet_launch.cell_spec import plan_layout, resolve_spec
    from armnet_launch.sim_cell import build_connector_config
    from armnet_runtime.lerobot.remote_object import encode_args
    from armnet_runtime.wire import decode, dumps_line, encode, loads_json
    from armnet_sim import SimulatedCellProcess
    from armnet_sim.calibration import builtin_calibration, write_calibration
    from armnet_sim.presets import PRESETS
    from lerobot.motors.feetech import FeetechMotorsBus

    spec = resolve_spec(embodiment=None, preset="so101", task=None, grace_seconds=None)
    with tempfile.TemporaryDirectory(prefix="armnet-profile-", dir="/dev/shm") as run_dir:
        layout = plan_layout(spec, Path(run_dir))
        for directory in (layout.socket_dir, layout.calibration_dir):
            directory.mkdir(parents=True, exist_ok=True)
        shipped = {arm.name: arm.calibration for arm in PRESETS[spec.preset]}
        calibrations = {}
        for arm in layout.arms:
            calibrations[arm.name] = builtin_calibration(shipped[arm.name])
            write_calibration(arm.calibration_file, calibrations[arm.name])
        with SimulatedCellProcess(spec.preset, calibrations=calibrations) as sim:
            ports = sim.ports()
            config = build_connector_config(spec, layout, ports)
            arm = layout.arms[0]
            bus_kwargs = so101_bus_kwargs(str(arm.calibration_file))
            with Connector(config, layout.socket_dir) as connector:
                session = RobotSession(connector.cell, connector.frames)

                def serve(request: dict[str, Any]) -> dict[str, Any]:
                    reply = session.handle(parse_request(dumps_line(request)))
                    return loads_json(encode_reply(reply))

                created = serve({"op": "create", "class": "FeetechMotorsBus", "args": [],
                                 "kwargs": encode({"port": arm.endpoint, **bus_kwargs})})
                object_id = created["object_id"]
                connect = {"op": "call", "object_id": object_id, "method": "connect", "args": [], "kwargs": {}}
                if not any(serve(connect)["ok"] for _ in range(3)):  # a starved simulator can miss a handshake
                    raise RuntimeError("the connector's bus could not connect to the simulator")
                direct = FeetechMotorsBus(port=ports[arm.name], **so101_bus_kwargs(str(arm.calibration_file)))
                connect_with_retries(direct)
                start = direct.sync_read("Present_Position")

                samples: dict[str, list[float]] = {
                    f"{kind}_{call}": [] for kind in ("direct", "client", "server", "directcpu", "servercpu")
                    for call in ("read", "write")
                }
                profiler = cProfile.Profile() if args.profile else None
                lost = 0
                stage_cpu: dict[str, list[float]] = {}
                current: dict[str, float] = {}
                undo_stages = instrument_stages(current) if args.stages else None

                def proxied(call: str, method: str, call_args: tuple[Any, ...]) -> None:
                    began = time.perf_counter()
                    line = dumps_line({"op": "call", "method": method, "args": encode_args(call_args),
                                       "kwargs": encode({}), "object_id": object_id})
                    current.clear()
                    middle, middle_cpu = time.perf_counter(), time.thread_time()
                    if profiler is not None:
                        profiler.enable()
                    request = parse_request(line)
                    parsed_cpu = time.thread_time()
                    reply = session.handle(request)
                    handled_cpu = time.thread_time()
                    reply_line = encode_reply(reply)
                    if profiler is not None:
                        profiler.disable()
                    after, after_cpu = time.perf_counter(), time.thread_time()
                    samples[f"servercpu_{call}"].append(after_cpu - middle_cpu)
                    if args.stages:
                        current["parse request line"] = parsed_cpu - middle_cpu
                        current["encode reply line"] = after_cpu - handled_cpu
                        current["session (dispatch, plan, lock, reply dict)"] = (handled_cpu - parsed_cpu) - sum(
                            v for k, v in current.items() if k in TOP_STAGES)
                        for stage, spent in current.items():
                            stage_cpu.setdefault(f"{method} {stage}", []).append(spent)
                    reply = loads_json(reply_line)
                    if not reply["ok"]:
                        raise RuntimeError(reply)
                    decode(reply.get("value"))
                    done = time.perf_counter()
                    samples[f"server_{call}"].append(after - middle)
                    samples[f"client_{call}"].append((middle - began) + (done - after))

                for tick in range(args.calls):
                    offset = WIGGLE_DEG * math.sin(tick / 20.0)
                    goals = {n: start[n] + (offset if n != "gripper" else 0.0) for n in SO101_JOINTS}
                    try:
                        # A pause before each call: the simulator is idle, as in a paced control loop.
                        time.sleep(PAUSE_S)
                        _timed(samples["direct_read"], samples["directcpu_read"], lambda: direct.sync_read("Present_Position"))
                        time.sleep(PAUSE_S)
                        proxied("read", "sync_read", ("Present_Position",))
                        time.sleep(PAUSE_S)
                        _timed(samples["direct_write"], samples["directcpu_write"], lambda goals=goals: direct.sync_write("Goal_Position", goals))
                        time.sleep(PAUSE_S)
                        proxied("write", "sync_write", ("Goal_Position", goals))
                    except (ConnectionError, RuntimeError):
                        lost += 1  # a starved simulator misses a reply now and then: count it, go on
                if undo_stages is not None:
                    undo_stages()
                hot = {}
                if args.hot:
                    proxy = proxy_on_session(session, object_id, arm.endpoint, bus_kwargs)
                    hot = hot_pieces(session, object_id, goals, start, args.hot_calls, proxy)
                direct.disconnect(disable_torque=False)
                session.close()

    print(f"{args.calls} ticks ({lost} lost a servo reply), p50 / p90 in microseconds")
    for call in ("read", "write"):
        row = {kind: samples[f"{kind}_{call}"] for kind in ("direct", "client", "server")}
        d50, s50 = percentile(row["direct"], 50) * 1e6, percentile(row["server"], 50) * 1e6
        print(f"sync_{call:<6} direct {d50:7.0f} / {percentile(row['direct'], 90) * 1e6:6.0f}"
              f"   server {s50:7.0f} / {percentile(row['server'], 90) * 1e6:6.0f}"
              f"   server - direct {s50 - d50:6.0f}"
              f"   client {percentile(row['client'], 50) * 1e6:5.0f} / {percentile(row['client'], 90) * 1e6:5.0f}")
        dc50 = percentile(samples[f"directcpu_{call}"], 50) * 1e6
        sc50 = percentile(samples[f"servercpu_{call}"], 50) * 1e6
        print(f"{'':12}CPU time (robust to a loaded machine): direct {dc50:5.0f}   server {sc50:5.0f}"
              f"   server - direct {sc50 - dc50:5.0f}")
    if stage_cpu:
        print("CPU time per stage of the connector's handling, p50 (microseconds):")
        for stage, values in stage_cpu.items():
            print(f"  {stage:<55} {percentile(values, 50) * 1e6:7.1f}")
    if hot:
        print(f"CPU time of each piece alone, tight loop, min of {HOT_BATCHES} batches (microseconds):")
        for piece, spent in hot.items():
            if isinstance(spent, tuple):
                print(f"  {piece:<70} {spent[0]:5d} / {spent[1]:6d}")
            else:
                print(f"  {piece:<70} {spent:7.2f}")
    if profiler is not None:
        stats = pstats.Stats(profiler)
        stats.sort_stats(args.sort).print_stats(args.top)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
