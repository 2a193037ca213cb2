"""Waiting for a lockstep peer (offboard.model.busywait): poll, then sleep. Real UDP sockets."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from offboard.model.busywait import LOCKSTEP_SPIN_S, poll_readable


@pytest.fixture
def pair():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield rx, tx
    rx.close()
    tx.close()


def test_a_datagram_that_arrives_while_polling_is_caught_awake(pair):
    rx, tx = pair
    sender = threading.Timer(0.002, lambda: tx.sendto(b"answer", rx.getsockname()))
    sender.start()
    try:
        readable = poll_readable([rx], spin_s=5.0)  # the datagram comes long before the 5 s
    finally:
        sender.join()
    assert readable == [rx]
    assert rx.recv(64) == b"answer"


def test_nothing_arriving_gives_up_after_the_spin_and_leaves_the_sleep_to_the_caller(pair):
    rx, _ = pair
    start = time.perf_counter()
    assert poll_readable([rx], spin_s=0.003) == []
    assert time.perf_counter() - start >= 0.003


def test_what_is_already_there_is_answered_at_once_and_file_numbers_work_too(pair):
    rx, tx = pair
    tx.sendto(b"x", rx.getsockname())
    time.sleep(0.01)
    assert poll_readable([rx.fileno()], spin_s=0.0) == [rx.fileno()]


def test_the_lockstep_spin_is_a_fraction_of_a_millisecond():
    """About twice a peer's turnaround (100-250 us); a wait longer than that sleeps."""
    assert 0.0 < LOCKSTEP_SPIN_S <= 0.001
