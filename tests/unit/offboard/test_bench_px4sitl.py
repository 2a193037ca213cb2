"""bench/px4sitl.py picks a PX4 SITL instance no other PX4 (another xdist worker's) is using.

No PX4 is started here: the probe binds real UDP sockets, and the retry runs a stand-in launcher.
"""

from __future__ import annotations

import os
import random
import re
import socket
import stat
from pathlib import Path

import pytest

from bench import px4sitl
from bench.px4sitl import INSTANCES, WORKER_SHARES, choose_instance, instance_free, instance_ports, running_px4


@pytest.mark.px4
def test_the_probed_ports_are_those_px4_binds_for_its_instance():
    launcher = px4sitl.px4_launcher()
    assert launcher is not None  # a px4 test: skipped without one (tests/conftest.py)
    script = (launcher.parent / "etc" / "init.d-posix" / "px4-rc.mavlink").read_text()
    local = sorted(int(base) for base in re.findall(r"_port_local=\$\(\((\d+)\+px4_instance\)\)", script))
    assert sorted(port - 7 for port in instance_ports(7)) == local


@pytest.mark.parametrize("worker", ["gw0", "gw1", "gw2", "gw3"])
def test_each_worker_first_takes_an_instance_of_its_own_share(worker):
    chosen = {choose_instance(worker=worker, is_free=lambda n: True, rng=random.Random(seed)) for seed in range(20)}
    assert chosen <= set(INSTANCES)
    assert {n % WORKER_SHARES for n in chosen} == {int(worker[2:]) % WORKER_SHARES}


def test_two_workers_starting_together_never_pick_the_same_instance():
    for seed in range(50):
        first = choose_instance(worker="gw0", is_free=lambda n: True, rng=random.Random(seed))
        second = choose_instance(worker="gw1", is_free=lambda n: True, rng=random.Random(seed))
        assert first != second


def test_busy_and_failed_instances_are_skipped_and_other_shares_used_when_its_own_is_full():
    busy = {n for n in INSTANCES if n % WORKER_SHARES == 0}
    chosen = choose_instance(worker="gw0", avoid=[21, 22], is_free=lambda n: n not in busy, rng=random.Random(1))
    assert chosen not in busy | {21, 22}
    with pytest.raises(RuntimeError, match="no free PX4 SITL instance"):
        choose_instance(worker="gw0", is_free=lambda n: False)


def test_an_instance_whose_port_is_bound_is_not_free_and_not_chosen():
    free = [n for n in INSTANCES if instance_free(n)]
    assert free, "every instance's ports are taken on this machine"
    taken = free[0]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("0.0.0.0", instance_ports(taken)[1]))  # as PX4 binds: every address
        assert not instance_free(taken)
        only_taken_left = lambda n: n == taken and instance_free(n)  # noqa: E731
        with pytest.raises(RuntimeError):
            choose_instance(is_free=only_taken_left)
    assert instance_free(taken)


def test_a_px4_that_does_not_start_on_its_instance_is_started_on_another(tmp_path, monkeypatch):
    # A stand-in for px4-sitl: refuses the first instance it is given as PX4 does when another
    # PX4 holds it, then starts a process that stands for PX4, which running_px4 must stop.
    calls = tmp_path / "calls"
    fake = tmp_path / "px4-sitl"
    fake.write_text(
        "#!/usr/bin/env bash\n"
        f'echo "$@" >> {calls}\n'
        f'if [ ! -e {tmp_path}/refused ]; then touch {tmp_path}/refused\n'
        '  echo "PX4 server already running for instance" >&2; exit 1; fi\n'
        "sleep 60 </dev/null >/dev/null 2>&1 &\n"
        'echo "PX4_PID=$!"\n'
    )  # fmt: skip
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PX4_SITL", str(fake))
    with running_px4(tmp_path / "px4") as px4:
        os.kill(px4.pid, 0)  # running
    instances = [int(re.search(r"--instance (\d+)", line).group(1)) for line in calls.read_text().splitlines()]
    assert len(instances) == 2 and instances[0] != instances[1]
    assert not running(px4.pid), "running_px4 left the stand-in for PX4 running"


def running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"  # a zombie has ended; its parent (init here) reaps it


def test_a_px4_that_never_starts_is_reported_with_every_instance_tried(tmp_path, monkeypatch):
    fake = tmp_path / "px4-sitl"
    fake.write_text('#!/usr/bin/env bash\necho "px4-sitl: PX4 did not become ready" >&2\nexit 1\n')
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PX4_SITL", str(fake))
    with pytest.raises(AssertionError, match=r"(?s)did not start.*--instance.*--instance.*--instance"):
        with running_px4(tmp_path / "px4"):
            pass


def test_the_worker_number_comes_from_pytest_xdist():
    assert px4sitl.worker_index("gw5") == 5
    assert px4sitl.worker_index(None) == 0
    assert px4sitl.worker_index("master") == 0
