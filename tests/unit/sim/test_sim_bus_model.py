"""Instruction handling on a multi-drop bus, byte for byte (docs/reference/feetech-lerobot.md, §1)."""

from __future__ import annotations

import pytest
from armnet_sim.bus_model import ServoBus
from armnet_sim.protocol import BROADCAST_ID, ErrorBit, Instr, Instruction, encode_status
from armnet_sim.servo import Servo, ServoFaults

pytestmark = pytest.mark.unit


def a_bus(*ids: int) -> ServoBus:
    return ServoBus(Servo(i) for i in ids)


def send(bus: ServoBus, servo_id: int, code: int, *params: int, now: float = 0.0) -> bytes:
    return bus.handle(Instruction(servo_id, code, bytes(params)), now)


def test_ping_answers_with_an_empty_status() -> None:
    assert send(a_bus(1), 1, Instr.PING) == bytes.fromhex("FFFF010200FC")


def test_read_model_number() -> None:
    assert send(a_bus(1), 1, Instr.READ, 3, 2) == bytes.fromhex("FFFF0104000903EE")


def test_write_applies_and_acknowledges() -> None:
    bus = a_bus(1)
    assert send(bus, 1, Instr.WRITE, 40, 1) == bytes.fromhex("FFFF010200FC")
    assert bus.servo(1).torque_on()  # type: ignore[union-attr]


def test_unknown_ids_stay_silent() -> None:
    assert send(a_bus(1), 9, Instr.PING) == b""
    assert send(a_bus(1), 9, Instr.READ, 3, 2) == b""


def test_broadcast_ping_answers_once_per_servo_in_id_order() -> None:
    bus = a_bus(3, 1, 2)
    expected = b"".join(encode_status(i, 0) for i in (1, 2, 3))
    assert send(bus, BROADCAST_ID, Instr.PING) == expected


def test_sync_read_answers_in_request_order() -> None:
    bus = a_bus(1, 2, 3)
    reply = send(bus, BROADCAST_ID, Instr.SYNC_READ, 5, 1, 3, 1, 2)
    assert reply == b"".join(encode_status(i, 0, bytes([i])) for i in (3, 1, 2))


def test_sync_read_skips_ids_that_are_not_on_the_bus() -> None:
    reply = send(a_bus(1, 2), BROADCAST_ID, Instr.SYNC_READ, 5, 1, 1, 7, 2)
    assert reply == encode_status(1, 0, b"\x01") + encode_status(2, 0, b"\x02")


def test_sync_write_applies_each_record_and_never_replies() -> None:
    bus = a_bus(1, 2)
    reply = send(bus, BROADCAST_ID, Instr.SYNC_WRITE, 41, 1, 1, 10, 2, 20)
    assert reply == b""
    assert [bus.servo(i).get("Acceleration") for i in (1, 2)] == [10, 20]  # type: ignore[union-attr]


def test_broadcast_write_applies_to_all_without_reply() -> None:
    bus = a_bus(1, 2)
    assert send(bus, BROADCAST_ID, Instr.WRITE, 41, 7) == b""
    assert all(s.get("Acceleration") == 7 for s in bus)


def test_an_unplugged_servo_neither_answers_nor_hears() -> None:
    bus = a_bus(1)
    bus.servo(1).set_faults(ServoFaults(unplugged=True))  # type: ignore[union-attr]
    assert send(bus, 1, Instr.PING) == b""
    assert send(bus, 1, Instr.WRITE, 41, 9) == b""
    assert send(bus, BROADCAST_ID, Instr.SYNC_WRITE, 41, 1, 1, 9) == b""
    assert bus.servo(1).get("Acceleration") == 0  # type: ignore[union-attr]


def test_checksum_fault_corrupts_only_that_servos_replies() -> None:
    bus = a_bus(1, 2)
    bus.servo(2).set_faults(ServoFaults(corrupt_checksum=True))  # type: ignore[union-attr]
    reply = send(bus, BROADCAST_ID, Instr.SYNC_READ, 5, 1, 1, 2)
    good, bad = reply[:7], reply[7:]
    assert good == encode_status(1, 0, b"\x01")
    assert bad[:-1] == encode_status(2, 0, b"\x02")[:-1] and bad != encode_status(2, 0, b"\x02")


def test_overload_sets_the_error_byte_and_the_status_register() -> None:
    bus = a_bus(1)
    bus.servo(1).set_faults(ServoFaults(error_bits=ErrorBit.OVERLOAD))  # type: ignore[union-attr]
    assert send(bus, 1, Instr.READ, 65, 1) == encode_status(1, 0x20, b"\x20")


def test_status_level_zero_silences_write_acks_but_not_reads() -> None:
    bus = a_bus(1)
    assert send(bus, 1, Instr.WRITE, 8, 0) == b""
    assert send(bus, 1, Instr.READ, 8, 1) == encode_status(1, 0, b"\x00")
    assert send(bus, 1, Instr.PING) == encode_status(1, 0)


def test_reg_write_waits_for_action() -> None:
    bus = a_bus(1)
    assert send(bus, 1, Instr.REG_WRITE, 41, 5) == encode_status(1, 0)
    assert bus.servo(1).get("Acceleration") == 0  # type: ignore[union-attr]
    assert send(bus, BROADCAST_ID, Instr.ACTION) == b""
    assert bus.servo(1).get("Acceleration") == 5  # type: ignore[union-attr]


def test_rewriting_the_id_moves_the_servo_to_its_new_address() -> None:
    bus = a_bus(1)
    send(bus, 1, Instr.WRITE, 5, 7)
    assert send(bus, 1, Instr.PING) == b""
    assert send(bus, 7, Instr.PING) == encode_status(7, 0)


def test_reset_restores_factory_eeprom() -> None:
    bus = a_bus(1)
    send(bus, 1, Instr.WRITE, 55, 0)
    send(bus, 1, Instr.WRITE, 9, 0x10, 0x00)
    assert send(bus, 1, Instr.RESET) == encode_status(1, 0)
    assert bus.servo(1).limits() == (0, 4095)  # type: ignore[union-attr]


def test_malformed_requests_are_ignored() -> None:
    bus = a_bus(1)
    assert send(bus, 1, Instr.READ, 3) == b""
    assert send(bus, 1, Instr.WRITE) == b""
    assert send(bus, BROADCAST_ID, Instr.SYNC_READ, 56) == b""
    assert send(bus, 1, 0x77) == b""


def test_transient_faults_affect_only_the_next_replies() -> None:
    bus = a_bus(1)
    bus.servo(1).set_faults(ServoFaults(drop_next=1, corrupt_next=1))  # type: ignore[union-attr]
    assert send(bus, 1, Instr.PING) == b""
    assert send(bus, 1, Instr.PING) != encode_status(1, 0)
    assert send(bus, 1, Instr.PING) == encode_status(1, 0)
