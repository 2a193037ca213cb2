"""The end-to-end helpers' own checks (``tests/helpers/flights.py``)."""

from __future__ import annotations

import signal
import socket
import subprocess

import pytest

from helpers.flights import PY, UdpProxy, free_udp_ports, stop_process


def test_free_udp_ports_are_distinct_and_bindable():
    ports = free_udp_ports(4)
    assert len(set(ports)) == 4
    for p in ports:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", p))
        s.close()


def test_proxy_forwards_both_ways_and_drops_on_request():
    plant = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    plant.bind(("127.0.0.1", 0))
    offboard = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    offboard.bind(("127.0.0.1", 0))
    for s in (plant, offboard):
        s.settimeout(2.0)
    with UdpProxy(plant.getsockname()[1], offboard.getsockname()[1]) as proxy:
        plant.sendto(b"telemetry", ("127.0.0.1", proxy.port))
        data, reply_to = offboard.recvfrom(100)
        assert data == b"telemetry"
        offboard.sendto(b"setpoint", reply_to)
        assert plant.recvfrom(100)[0] == b"setpoint"
        proxy.drop = True
        plant.sendto(b"lost", ("127.0.0.1", proxy.port))
        offboard.settimeout(0.3)
        with pytest.raises(socket.timeout):
            offboard.recvfrom(100)
        assert proxy.dropped == 1
    plant.close()
    offboard.close()


def test_stop_process_ends_a_child_that_ignores_sigint():
    child = subprocess.Popen([PY, "-c", "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('ready', flush=True); "
                                        "time.sleep(60)"], stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert child.stdout is not None and child.stdout.readline() == "ready\n"  # SIGINT ignored from now on (a fixed wait lost to a loaded host)
    code = stop_process(child, signal.SIGINT, timeout_s=0.5)
    child.stdout.close()
    assert child.poll() is not None and code == -signal.SIGKILL


def test_the_timesync_line_says_what_the_offset_is():
    from offboard.commands.fly import format_timesync

    assert format_timesync(-326423.490, 0.329) == (
        "timesync: the vehicle's clock is 326.423 s behind ours (offset -326423.490 ms: where the two clocks started, "
        "not an error), round trip 0.329 ms")  # fmt: skip
    assert "2.500 s ahead of ours" in format_timesync(2500.0, 1.0)
