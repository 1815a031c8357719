"""The outbox keeps messages in publish order across memory and the disk spool, within its bounds."""

from __future__ import annotations

from pathlib import Path

import pytest
from armnet_node import stream_outbox
from armnet_node.stream_outbox import Outbox, OutMessage

pytestmark = pytest.mark.unit


def message(seq: int, size: int = 100) -> OutMessage:
    return OutMessage("logs.ns.job.stdout", f"{seq:06d}".encode().ljust(size, b"."), f"job:stdout:{seq}")


def drain(outbox: Outbox, batch: int = 7) -> list[str]:
    """Take everything out in batches, as the sender does: peek, then remove what was acknowledged."""
    ids: list[str] = []
    while True:
        taken = outbox.peek(batch)
        if not taken:
            return ids
        ids.extend(m.msg_id for m in taken)
        outbox.remove(len(taken))


def test_messages_beyond_memory_go_to_the_spool_and_come_back_in_order(tmp_path: Path) -> None:
    outbox = Outbox(memory_max_bytes=1000, spool_dir=tmp_path, spool_max_bytes=1 << 20)
    for seq in range(100):
        assert outbox.put(message(seq))
    assert outbox.spooled > 0 and len(outbox) == 100
    assert drain(outbox) == [f"job:stdout:{seq}" for seq in range(100)]
    assert outbox.dropped == 0


def test_while_the_spool_holds_messages_new_ones_queue_behind_them(tmp_path: Path) -> None:
    outbox = Outbox(memory_max_bytes=1000, spool_dir=tmp_path, spool_max_bytes=1 << 20)
    for seq in range(30):
        outbox.put(message(seq))
    taken = outbox.peek(5)
    outbox.remove(len(taken))  # memory has room again, but older messages still wait on disk
    for seq in range(30, 40):
        outbox.put(message(seq))
    assert [m.msg_id for m in taken] + drain(outbox) == [f"job:stdout:{seq}" for seq in range(40)]


def test_a_peeked_message_stays_until_removed(tmp_path: Path) -> None:
    outbox = Outbox(memory_max_bytes=1000, spool_dir=tmp_path, spool_max_bytes=1 << 20)
    outbox.put(message(0))
    assert outbox.peek(10) == outbox.peek(10) == [message(0)]
    outbox.remove(1)
    assert outbox.peek(10) == []


def test_beyond_memory_and_spool_messages_are_dropped_and_counted(tmp_path: Path) -> None:
    outbox = Outbox(memory_max_bytes=1000, spool_dir=tmp_path, spool_max_bytes=2000)
    accepted = sum(outbox.put(message(seq)) for seq in range(100))
    assert outbox.dropped == 100 - accepted > 0
    assert len(outbox) == accepted


def test_without_a_spool_directory_only_memory_holds_messages() -> None:
    outbox = Outbox(memory_max_bytes=1000, spool_dir=None, spool_max_bytes=1 << 20)
    accepted = sum(outbox.put(message(seq)) for seq in range(100))
    assert accepted == 1000 // message(0).size
    assert (outbox.spooled, outbox.dropped) == (0, 100 - accepted)


def test_sent_spool_segments_are_deleted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(stream_outbox, "SEGMENT_BYTES", 1000)
    outbox = Outbox(memory_max_bytes=500, spool_dir=tmp_path, spool_max_bytes=1 << 20)
    for seq in range(200):
        outbox.put(message(seq))
    assert len(list(tmp_path.glob("*.seg"))) > 5
    assert drain(outbox, batch=50) == [f"job:stdout:{seq}" for seq in range(200)]
    assert list(tmp_path.glob("*.seg")) == []


def test_the_spool_bounds_what_waits_not_what_was_ever_written(tmp_path: Path) -> None:
    outbox = Outbox(memory_max_bytes=300, spool_dir=tmp_path, spool_max_bytes=3000)
    for round_ in range(20):  # far more than 3000 bytes in total, never more than 3000 waiting
        for seq in range(10):
            assert outbox.put(message(round_ * 10 + seq))
        drain(outbox)
    assert outbox.dropped == 0


def test_an_earlier_processs_spool_is_discarded_at_start(tmp_path: Path) -> None:
    (tmp_path / "armnet-nats-1-00000000.seg").write_bytes(message(0).encode())
    outbox = Outbox(memory_max_bytes=1000, spool_dir=tmp_path, spool_max_bytes=1 << 20)
    assert len(outbox) == 0 and list(tmp_path.glob("*.seg")) == []


def test_discarding_everything_counts_it_as_dropped(tmp_path: Path) -> None:
    outbox = Outbox(memory_max_bytes=1000, spool_dir=tmp_path, spool_max_bytes=1 << 20)
    for seq in range(50):
        outbox.put(message(seq))
    assert outbox.discard_all() == 50
    assert (outbox.dropped, len(outbox)) == (50, 0)
    assert list(tmp_path.glob("*.seg")) == []
