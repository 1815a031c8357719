"""Framing of the Feetech protocol: what the simulator accepts off the wire."""

from __future__ import annotations

import pytest
from armnet_sim.protocol import FrameParser, Instr, Instruction, checksum, encode_status

pytestmark = pytest.mark.unit

PING_1 = bytes.fromhex("FFFF010201FB")
READ_MODEL_1 = bytes.fromhex("FFFF0104020302F3")


def test_checksum_matches_the_reference_examples() -> None:
    assert checksum(bytes([0x01, 0x02, 0x01])) == 0xFB
    assert Instruction(1, Instr.PING).encode() == PING_1
    assert Instruction(1, Instr.READ, bytes([3, 2])).encode() == READ_MODEL_1
    assert Instruction(1, Instr.WRITE, bytes([42, 0x71, 0x08])).encode() == bytes.fromhex(
        "FFFF0105032A710853"
    )


def test_status_packet_layout_and_corruption() -> None:
    assert encode_status(1, 0, bytes([0x09, 0x03])) == bytes.fromhex("FFFF0104000903EE")
    bad = encode_status(1, 0, bytes([0x09, 0x03]), corrupt=True)
    assert bad[:-1] == bytes.fromhex("FFFF0104000903") and bad[-1] != 0xEE


def test_a_frame_split_into_single_bytes_is_assembled() -> None:
    parser = FrameParser()
    frames = [f for byte in READ_MODEL_1 for f in parser.feed(bytes([byte]))]
    assert frames == [Instruction(1, Instr.READ, bytes([3, 2]))]


def test_coalesced_frames_are_all_returned_in_order() -> None:
    parser = FrameParser()
    frames = parser.feed(PING_1 + READ_MODEL_1 + PING_1)
    assert [f.code for f in frames] == [Instr.PING, Instr.READ, Instr.PING]


def test_garbage_before_a_header_is_skipped() -> None:
    assert FrameParser().feed(b"\x00\x13\xff\x42" + PING_1) == [Instruction(1, Instr.PING)]


def test_a_bad_checksum_drops_the_frame_silently_and_the_next_one_parses() -> None:
    parser = FrameParser()
    corrupted = PING_1[:-1] + b"\x00"
    assert parser.feed(corrupted + READ_MODEL_1) == [Instruction(1, Instr.READ, bytes([3, 2]))]
    assert parser.dropped_frames == 1


def test_an_extra_ff_before_the_header_resyncs() -> None:
    assert FrameParser().feed(b"\xff" + PING_1) == [Instruction(1, Instr.PING)]


def test_an_impossible_length_resyncs_onto_the_real_frame() -> None:
    assert FrameParser().feed(b"\xff\xff\x01\x00" + PING_1) == [Instruction(1, Instr.PING)]


def test_a_stale_partial_frame_does_not_swallow_the_retry() -> None:
    parser = FrameParser(stale_after_s=0.02)
    assert parser.feed(READ_MODEL_1[:4], now=1.0) == []
    assert parser.feed(PING_1, now=1.5) == [Instruction(1, Instr.PING)]


def test_a_partial_frame_completed_promptly_is_kept() -> None:
    parser = FrameParser(stale_after_s=0.02)
    assert parser.feed(READ_MODEL_1[:4], now=1.0) == []
    assert parser.feed(READ_MODEL_1[4:], now=1.001) == [Instruction(1, Instr.READ, bytes([3, 2]))]


def test_a_late_continuation_that_is_not_a_new_header_is_kept() -> None:
    parser = FrameParser(stale_after_s=0.02)
    assert parser.feed(READ_MODEL_1[:4], now=1.0) == []
    assert parser.feed(READ_MODEL_1[4:], now=1.5) == [Instruction(1, Instr.READ, bytes([3, 2]))]
