"""A UDP relay that delays every datagram, as a slow radio or network link does, or cuts it.

Sits between ``sitl-plant`` and ``offboard fly`` (the plant's ``--api-remote`` is ``port``):
each datagram, either way, is sent on ``delay_s`` +- ``jitter_s`` (uniform, seeded) after it
arrived, and never before the one that arrived ahead of it (a link's queue keeps the order; a
jitter that reordered datagrams would be another fault, issue 14's). ``drop = True`` cuts the
link both ways (datagrams counted in ``dropped``); with ``delay_s = 0`` datagrams are forwarded
at once (the tests' link-outage proxy).

    with DelayedLink(plant_port, offboard_port, delay_s=0.05, jitter_s=0.02) as link:
        ... start sitl-plant with --api-remote 127.0.0.1:{link.port} ...
"""

from __future__ import annotations

import heapq
import random
import socket
import threading
import time


class DelayedLink:
    """Forward datagrams both ways between the plant and the offboard, each one delayed."""

    def __init__(self, plant_port: int, offboard_port: int, *, delay_s: float, jitter_s: float = 0.0, seed: int = 1) -> None:
        if not (0.0 <= jitter_s <= delay_s):
            raise ValueError(f"need 0 <= jitter ({jitter_s}) <= delay ({delay_s})")
        self.delay_s, self.jitter_s = delay_s, jitter_s
        self._rng = random.Random(seed)
        self.plant_addr = ("127.0.0.1", plant_port)
        self.offboard_addr = ("127.0.0.1", offboard_port)
        self.plant_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.plant_side.bind(("127.0.0.1", 0))
        self.offboard_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.offboard_side.bind(("127.0.0.1", 0))
        for s in (self.plant_side, self.offboard_side):
            s.settimeout(0.01)
        self.port = self.plant_side.getsockname()[1]
        self.drop = False
        self.dropped = 0
        self.forwarded = 0
        self._queue: list[tuple[float, int, socket.socket, bytes, tuple[str, int]]] = []
        self._last_due = {id(self.plant_side): 0.0, id(self.offboard_side): 0.0}
        self._count = 0
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._receive, args=(self.plant_side, self.offboard_side, self.offboard_addr), daemon=True),
            threading.Thread(target=self._receive, args=(self.offboard_side, self.plant_side, self.plant_addr), daemon=True),
            threading.Thread(target=self._send, daemon=True),
        ]

    def _receive(self, src: socket.socket, dst: socket.socket, addr: tuple[str, int]) -> None:
        while not self._stop.is_set():
            try:
                data, _ = src.recvfrom(65535)
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            if self.drop:
                self.dropped += 1
                continue
            if self.delay_s == 0.0:
                self._forward(dst, data, addr)
                continue
            now = time.monotonic()
            with self._wake:
                delay = self.delay_s + self._rng.uniform(-self.jitter_s, self.jitter_s)
                due = max(now + delay, self._last_due[id(src)])  # in order, per direction
                self._last_due[id(src)] = due
                self._count += 1
                heapq.heappush(self._queue, (due, self._count, dst, data, addr))
                self._wake.notify()

    def _send(self) -> None:
        while not self._stop.is_set():
            with self._wake:
                if not self._queue:
                    self._wake.wait(0.05)
                    continue
                due = self._queue[0][0]
                wait = due - time.monotonic()
                if wait > 0:
                    self._wake.wait(min(wait, 0.05))
                    continue
                _, _, dst, data, addr = heapq.heappop(self._queue)
            self._forward(dst, data, addr)

    def _forward(self, dst: socket.socket, data: bytes, addr: tuple[str, int]) -> None:
        try:
            dst.sendto(data, addr)
            self.forwarded += 1
        except OSError:
            pass

    def __enter__(self) -> DelayedLink:
        for t in self._threads:
            t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        with self._wake:
            self._wake.notify_all()
        for t in self._threads:
            t.join(timeout=2)
        self.plant_side.close()
        self.offboard_side.close()
