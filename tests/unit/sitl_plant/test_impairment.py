"""The plant's bad link (sitl_plant/impairment.py), and the link applying it on real sockets."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_plant.impairment import DelayLine, Impairment, ImpairmentError, ImpairmentSpec, parse_impairment
from sitl_plant.link import Endpoint, Link


def test_the_spec_reads_every_key_and_names_a_bad_field():
    assert parse_impairment("loss=20,delay=50,jitter=20") == ImpairmentSpec(loss=20, delay=50, jitter=20)
    assert parse_impairment("duplicate=1%, reorder=2, corrupt=0.5, delay=10ms") == ImpairmentSpec(
        delay=10, duplicate=1, reorder=2, corrupt=0.5)
    for text, says in [("loss=120", "loss must be 0..100"), ("delay=-1", "delay must be >= 0"), ("loss", "not KEY=VALUE"),
                       ("wobble=3", "not KEY=VALUE"), ("loss=x", "loss='x' is not a number"),
                       ("delay=10,jitter=20", "jitter 20 ms exceeds the delay 10 ms"), ("loss=nan", "loss must be")]:  # fmt: skip
        with pytest.raises(ImpairmentError) as err:
            parse_impairment(text, "--link-in")
        assert str(err.value).startswith(f"--link-in {text!r}: ") and says in str(err.value), str(err.value)


def test_seeded_fates_at_the_rates_asked():
    spec = ImpairmentSpec(loss=20, delay=50, jitter=20, duplicate=5, reorder=10, corrupt=2)
    a, b = Impairment(spec, "7/api/in"), Impairment(spec, "7/api/in")
    datagram = bytes(range(40))
    fates = [a.schedule(datagram, 0.0) for _ in range(20_000)]
    assert fates == [b.schedule(datagram, 0.0) for _ in range(20_000)]  # the same seed, the same fates
    assert fates != [Impairment(spec, "8/api/in").schedule(datagram, 0.0) for _ in range(20_000)]
    n = 20_000
    c = a.counts
    assert c.datagrams == n
    assert c.dropped / n == pytest.approx(0.20, abs=0.015)
    assert c.duplicated / (n - c.dropped) == pytest.approx(0.05, abs=0.01)
    delays = [t for fate in fates for t, _ in fate]
    held = [t for t in delays if t > 0]
    assert min(held) >= 0.030 - 1e-12 and max(held) <= 0.070 + 1e-12
    assert sum(held) / len(held) == pytest.approx(0.050, abs=0.001)
    assert (len(delays) - len(held)) / len(delays) == pytest.approx(0.10, abs=0.01)  # reordered: not delayed
    copies = [d for fate in fates for _, d in fate]
    flipped = [d for d in copies if d != datagram]
    assert len(flipped) == c.corrupted and c.corrupted / len(copies) == pytest.approx(0.02, abs=0.005)
    assert all(sum(bin(x ^ y).count("1") for x, y in zip(d, datagram)) == 1 for d in flipped)  # one bit each


def test_the_delay_line_releases_in_time_order():
    line = DelayLine()
    for t, name in [(0.3, b"c"), (0.1, b"a"), (0.2, b"b"), (0.1, b"a2")]:
        line.push(t, name)
    assert line.next_release_s() == 0.1 and line.due(0.05) == []
    assert [d for d, _ in line.due(0.2)] == [b"a", b"a2", b"b"]
    assert len(line) == 1 and [d for d, _ in line.due(1.0)] == [b"c"] and line.next_release_s() is None


def test_a_delayed_lossy_link_on_real_sockets():
    """What the plant sends: 200 datagrams at 1 ms spacing through loss 25 %, delay 40 +- 10 ms."""
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.settimeout(0.2)
    impair = Impairment(ImpairmentSpec(loss=25, delay=40, jitter=10), seed=3)
    endpoint = Endpoint("api", ("127.0.0.1", 0), peer.getsockname(), 1, 1, impair_out=impair)
    link = Link([endpoint], None, lambda: 0)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    sent_at = {}
    arrived = {}
    peer.setblocking(False)

    def drain() -> None:
        while True:
            try:
                data = peer.recv(65535)
            except BlockingIOError:
                return
            for m in mavlink.MAVLink(None).parse_buffer(data) or []:
                arrived[m.time_boot_ms] = time.monotonic()

    try:
        for i in range(200):
            msg = mavlink.MAVLink_system_time_message(0, i)
            sent_at[i] = time.monotonic()
            endpoint.send_datagram(msg.pack(mav))  # (releases what fell due meanwhile)
            drain()
            time.sleep(0.001)
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            link.wait(0.002)
            link.receive()  # releases what fell due
            drain()
            if len(endpoint._held_out) == 0 and len(arrived) + impair.counts.dropped >= 200:
                break
    finally:
        link.close()
        peer.close()
    assert len(arrived) == 200 - impair.counts.dropped and 30 <= impair.counts.dropped <= 70
    delays = sorted(arrived[i] - sent_at[i] for i in arrived)
    assert delays[0] >= 0.029  # never early (scheduling may only make it later)
    assert delays[len(delays) // 2] < 0.060  # about the 40 ms asked, typically
    order = sorted(arrived, key=arrived.get)
    assert order != sorted(order)  # 10 ms of jitter at 1 ms spacing reorders them


def test_the_status_line_says_what_the_bad_link_did():
    impair = Impairment(ImpairmentSpec(loss=50), seed=1)
    for _ in range(100):
        impair.schedule(b"x" * 20, 0.0)
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1, impair_in=impair)
    clean = Endpoint("gcs", ("127.0.0.1", 0), None, 1, 1)
    try:
        assert Link([clean], None, lambda: 0).impairment_status() == ""
        assert Link([endpoint, clean], None, lambda: 0).impairment_status() == f" link: {impair.counts.dropped} dropped, 0 duplicated, 0 corrupted"
        assert 30 < impair.counts.dropped < 70
    finally:
        endpoint.close()
        clean.close()
