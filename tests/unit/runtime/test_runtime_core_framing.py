"""armnet_core.framing: the one JSON-lines framing of every armnet socket.

The connector's hostile-input tests (tests/unit/connector/test_connector_limits.py)
drive it through a server; these pin what the SDK and the node agent rely on.
"""

from __future__ import annotations

import socket
import threading
import time

import pytest
from armnet_core.framing import BudgetExhausted, BufferBudget, LineReader, LineTooLong


def test_lines_come_one_at_a_time_and_bytes_after_a_line_wait_for_the_next() -> None:
    left, right = socket.socketpair()
    with left, right:
        reader = LineReader(right, limit=100)
        left.sendall(b'{"a":1}\n{"b":')
        assert reader.next() == b'{"a":1}\n'
        assert reader.pending == len(b'{"b":')
        left.sendall(b"2}\n")
        assert reader.next() == b'{"b":2}\n' and reader.pending == 0


def test_a_clean_close_gives_an_empty_line_and_a_close_mid_line_the_rest() -> None:
    left, right = socket.socketpair()
    with right:
        reader = LineReader(right, limit=100)
        left.sendall(b"half")
        left.close()
        assert reader.next() == b"half"
        assert reader.next() == b""


def test_a_peer_that_trickles_bytes_is_cut_off_at_the_deadline() -> None:
    left, right = socket.socketpair()
    stop = threading.Event()

    def trickle() -> None:
        while not stop.wait(0.02):
            left.sendall(b"x")

    writer = threading.Thread(target=trickle)
    writer.start()
    try:
        reader = LineReader(right, limit=1000)
        started = time.monotonic()
        with pytest.raises(TimeoutError):
            reader.next(started + 0.3)
        assert time.monotonic() - started < 2.0
    finally:
        stop.set()
        writer.join(timeout=5)
        left.close()
        right.close()


def test_a_line_over_the_limit_says_the_limit() -> None:
    left, right = socket.socketpair()
    with left, right:
        left.sendall(b"z" * 300)
        with pytest.raises(LineTooLong, match="longer than 200 bytes") as caught:
            LineReader(right, limit=200).next()
        assert caught.value.limit == 200


def test_a_whole_line_over_the_limit_in_one_chunk_is_refused_too() -> None:
    left, right = socket.socketpair()
    with left, right:
        reader = LineReader(right, limit=10)
        left.sendall(b"x" * 10 + b"\n" + b"y" * 20 + b"\n")
        assert reader.next() == b"x" * 10 + b"\n"  # exactly the limit, and its newline
        with pytest.raises(LineTooLong):
            reader.next()


def test_the_shared_budget_refuses_the_reader_that_would_go_over_and_gets_its_bytes_back() -> None:
    budget = BufferBudget(limit=10)
    (a_left, a_right), (b_left, b_right) = socket.socketpair(), socket.socketpair()
    with a_left, a_right, b_left, b_right:
        first, second = LineReader(a_right, limit=100, budget=budget), LineReader(b_right, limit=100, budget=budget)
        a_left.sendall(b"123456789")
        a_left.shutdown(socket.SHUT_WR)
        assert first.next() == b"123456789" and budget.used == 0  # held while unfinished, given back at the close
        b_left.sendall(b"abcdef")
        b_left.sendall(b"ghijkl")
        with pytest.raises(BudgetExhausted):
            second.next()
        second.close()
        assert budget.used == 0
