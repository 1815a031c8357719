"""A goal SYNC_WRITE is applied once the line is quiet, at its arrival time: no observer can tell.

Why the simulator defers it: see ``sim_bus`` and ``pty_server`` (a real servo
applies a write on its own CPU; the simulator's thread would hold the host's).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator

import pytest
from armnet_sim.bus_model import ServoBus
from armnet_sim.protocol import BROADCAST_ID, Instr, Instruction, is_lone_sync_write
from armnet_sim.pty_server import PtyServer
from armnet_sim.servo import Servo
from armnet_sim.sim_bus import MAX_DEFERRED_WRITES, SimulatedBus

pytestmark = pytest.mark.unit

TORQUE_ENABLE, GOAL_POSITION, PRESENT_POSITION = 40, 42, 56


def goals_frame(goals: dict[int, int]) -> bytes:
    records = b"".join(bytes([servo_id, goal & 0xFF, goal >> 8]) for servo_id, goal in goals.items())
    return Instruction(BROADCAST_ID, Instr.SYNC_WRITE, bytes([GOAL_POSITION, 2]) + records).encode()


def torque_on_frame() -> bytes:
    return Instruction(BROADCAST_ID, Instr.SYNC_WRITE, bytes([TORQUE_ENABLE, 1, 1, 1, 2, 1])).encode()


def read_frame(servo_id: int, address: int) -> bytes:
    return Instruction(servo_id, Instr.READ, bytes([address, 2])).encode()


def test_only_one_whole_valid_broadcast_sync_write_is_a_lone_sync_write() -> None:
    frame = goals_frame({1: 2100, 2: 1900})
    assert is_lone_sync_write(frame)
    assert not is_lone_sync_write(frame[:-1])  # unfinished
    assert not is_lone_sync_write(frame[:-1] + bytes([frame[-1] ^ 0xFF]))  # bad checksum
    assert not is_lone_sync_write(frame + read_frame(1, PRESENT_POSITION))  # a request rides along
    assert not is_lone_sync_write(Instruction(1, Instr.WRITE, bytes([GOAL_POSITION, 0, 8])).encode())  # acked
    assert not is_lone_sync_write(Instruction(BROADCAST_ID, Instr.SYNC_READ, bytes([56, 2, 1, 2])).encode())
    assert not is_lone_sync_write(Instruction(BROADCAST_ID, Instr.PING).encode())


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def wired() -> Iterator[tuple[SimulatedBus, int, Clock]]:
    clock = Clock()
    bus = SimulatedBus([Servo(1), Servo(2)], clock=clock).start()
    port = os.open(bus.port, os.O_RDWR | os.O_NOCTTY)
    try:
        yield bus, port, clock
    finally:
        os.close(port)
        bus.stop()


def ask(port: int, request: bytes, length: int) -> bytes:
    os.write(port, request)
    reply, deadline = b"", time.monotonic() + 5
    while len(reply) < length and time.monotonic() < deadline:
        reply += os.read(port, length - len(reply))
    return reply


def test_servos_behave_as_if_each_write_were_applied_on_arrival(wired: tuple[SimulatedBus, int, Clock]) -> None:
    bus, port, clock = wired
    reference = ServoBus([Servo(1), Servo(2)])
    reference_frames = []
    for at, frame in ((0.0, torque_on_frame()), (1.0, goals_frame({1: 2600, 2: 1500}))):
        clock.now = at
        os.write(port, frame)
        time.sleep(0.05)  # its own chunk, read at this time; the line then goes quiet
        reference_frames.append((at, frame))
    clock.now = 1.2  # mid-move: a write applied at any other time would put the joints elsewhere
    replies = [ask(port, read_frame(i, PRESENT_POSITION), 8) for i in (1, 2)]
    for at, frame in reference_frames:
        reference.handle(Instruction(frame[2], frame[4], frame[5:-1]), at)
    expected = [reference.handle(Instruction(i, Instr.READ, bytes([PRESENT_POSITION, 2])), 1.2) for i in (1, 2)]
    assert replies == expected
    moved = [int.from_bytes(reply[5:7], "little") for reply in replies]
    assert moved[0] > 2048 > moved[1]  # the goals took effect (both servos start at 2048)


def test_a_kept_write_reaches_the_servos_before_a_request_or_an_inspection_at_its_arrival_time() -> None:
    clock = Clock()
    bus = SimulatedBus([Servo(1), Servo(2)], clock=clock)  # not started: the handler is driven directly
    on_bytes = bus._on_bytes  # noqa: SLF001 - what the pty thread calls with each chunk
    assert on_bytes(torque_on_frame(), 0.0) == b""  # torque off, a servo's goal follows its position
    assert on_bytes(goals_frame({1: 3000, 2: 1000}), 0.5) == b""
    assert on_bytes(read_frame(1, GOAL_POSITION), 0.5)[5:7] == (3000).to_bytes(2, "little")
    assert on_bytes(goals_frame({1: 2500, 2: 1500}), 1.0) == b""
    clock.now = 1.2

    def seen(model: ServoBus, now: float) -> list[tuple[int, int]]:
        return [(model.servo(i).get("Goal_Position"), model.servo(i).present_position(now)) for i in (1, 2)]

    reference = ServoBus([Servo(1), Servo(2)])
    for at, frame in ((0.0, torque_on_frame()), (0.5, goals_frame({1: 3000, 2: 1000})),
                      (1.0, goals_frame({1: 2500, 2: 1500}))):
        reference.handle(Instruction(frame[2], frame[4], frame[5:-1]), at)
    assert bus.inspect(seen) == seen(reference, 1.2)
    assert [goal for goal, _position in bus.inspect(seen)] == [2500, 1500]


def test_the_pty_server_runs_on_quiet_after_an_unanswered_request_only() -> None:
    quiet = threading.Event()
    server = PtyServer(lambda data, _now: b"" if data == b"w" else data, on_quiet=quiet.set, quiet_after_s=0.005)
    server.start()
    try:
        port = os.open(server.port, os.O_RDWR | os.O_NOCTTY)
        try:
            assert ask(port, b"r", 1) == b"r"
            assert not quiet.wait(0.1)  # answered: nothing was left for later
            os.write(port, b"w")
            assert quiet.wait(5)
        finally:
            os.close(port)
    finally:
        server.stop()


def test_a_sender_that_never_pauses_keeps_at_most_a_bounded_number_of_writes() -> None:
    bus = SimulatedBus([Servo(1), Servo(2)], clock=Clock())  # not started: no quiet line ever comes
    on_bytes = bus._on_bytes  # noqa: SLF001 - what the pty thread calls with each chunk
    on_bytes(torque_on_frame(), 0.0)
    for tick in range(10 * MAX_DEFERRED_WRITES):
        on_bytes(goals_frame({1: 2048 + tick % 100, 2: 2048}), tick * 0.001)
    assert len(bus._deferred) <= MAX_DEFERRED_WRITES  # noqa: SLF001 - the bound is the point
    assert bus.inspect(lambda model, _now: model.servo(1).get("Goal_Position")) == 2048 + (10 * MAX_DEFERRED_WRITES - 1) % 100
