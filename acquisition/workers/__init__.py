"""Worker processes of ``sarbot run``: what consumes the drivers' data live (odometry, strip map).

Every worker has the same run loop (``run_worker``): subscribe to its topics, handle each message while
live, drain what the drivers send on their way out, finish (the last results onto the bus), and write its
products whatever happened. A worker is described by a ``WorkerSpec``; the daemon starts each in a
process of its own with ``worker_process``.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

from ..bus import BusPublisher, BusSubscriber
from ..messages import BusMessage, decode
from ..processes import become_child, free_tcp_endpoint


class Worker:
    """The skeleton a worker fills in. Built in its process as ``cls(config, publisher)``.

    ``topics`` (prefixes) and ``endpoints`` (besides the drivers') say what it subscribes to.
    Draining at the end lasts until ``drained(message)`` says the last expected message came, until
    nothing came for ``drain_quiet_s``, or for at most ``drain_max_s``.
    """

    topics: list[str] = []
    endpoints: list[str] = []
    drain_quiet_s: float = 0.5
    drain_max_s: float = 10.0

    def handle(self, message: BusMessage, live: bool) -> None:
        """One message. ``live`` False while draining: nothing may be dropped then."""

    def step(self) -> None:
        """After every receive while live (imaging what is ready, publishing on a schedule)."""

    def drained(self, message: BusMessage) -> bool:
        """True for the message after which nothing more is expected."""
        return False

    def finish(self) -> None:
        """After draining: the last results onto the bus."""

    def write_products(self) -> None:
        """Always, also after an error: the worker's files (trajectory, map)."""


def run_worker(worker: Worker, sub: BusSubscriber, stop) -> None:
    """The run loop every worker shares: live until ``stop`` is set, then drain, then finish."""
    while not stop.is_set():
        msg = sub.receive(timeout_ms=50)
        if msg is not None:
            worker.handle(decode(msg), live=True)
        worker.step()
    now = time.monotonic()
    deadline, quiet_until = now + worker.drain_max_s, now + worker.drain_quiet_s
    while (now := time.monotonic()) < deadline and now < quiet_until:
        msg = sub.receive(timeout_ms=100)
        if msg is None:
            continue
        quiet_until = time.monotonic() + worker.drain_quiet_s
        message = decode(msg)
        if worker.drained(message):
            break
        worker.handle(message, live=False)
    worker.finish()


@dataclasses.dataclass
class WorkerSpec:
    """A worker for the daemon: ``worker`` (a Worker subclass) built with ``config`` in a process named
    ``role`` that publishes on ``endpoint``."""

    role: str
    worker: type
    config: Any
    endpoint: str = dataclasses.field(default_factory=free_tcp_endpoint)


def worker_process(spec: WorkerSpec, driver_endpoints: list[str], stop) -> None:
    """A worker's process: subscribe to the drivers (and the worker's own extra endpoints), run, write."""
    become_child(spec.role)
    pub = BusPublisher(spec.endpoint)
    worker = spec.worker(spec.config, pub)
    sub = BusSubscriber([*driver_endpoints, *worker.endpoints], topics=worker.topics)
    try:
        run_worker(worker, sub, stop)
        time.sleep(0.2)  # let the subscribers take the last messages before the socket closes
    finally:
        worker.write_products()
        pub.close()
        sub.close()
