"""Worker processes of ``sarbot run``: what consumes the drivers' data live (odometry, strip map).

Every worker has the same run loop (``run_worker``): subscribe to its topics, handle each message while
live, drain what the drivers send on their way out, finish (the last results onto the bus), and write its
products whatever happened. A worker is described by a ``WorkerSpec``; the daemon starts each in a
process of its own with ``worker_process``.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any

from ..bus import FRAME_QUEUE, BusPublisher, BusSubscriber
from ..messages import BusMessage, WorkerState, decode
from ..processes import become_child, bus_endpoint, release_free_heap

log = logging.getLogger(f"sarbot.{__name__}")

#: Most messages a worker takes from its socket between two steps.
MAX_BATCH = 1000


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

    def warm_up(self) -> None:
        """Compile the kernels on representative shapes before the first real message (a cold JIT cache
        costs tens of seconds); messages that arrive meanwhile queue and are handled in order after."""

    def counters(self) -> dict[str, int]:
        """What the worker counts for health (e.g. scans it had to leave out); published every second."""
        return {}

    def calibration(self) -> dict[str, dict]:
        """What the worker has calibrated, for health (``WorkerState.calibration``); published every second."""
        return {}

    def handle(self, message: BusMessage, live: bool) -> None:
        """One message. ``live`` False while draining: nothing may be dropped then."""

    def step(self) -> None:
        """After every batch of receives while live (imaging what is ready, publishing on a schedule). It
        should return within a fraction of a second, so the socket is drained in time."""

    def drained(self, message: BusMessage) -> bool:
        """True for the message after which nothing more is expected."""
        return False

    def lost_on_bus(self, missed: dict[str, int]) -> None:
        """Messages lost on the bus so far by topic (sequence gaps: a full queue), given before every step
        and before ``finish``, for the worker to account for them in its results."""

    def finish(self) -> None:
        """After draining: the last results onto the bus."""

    def write_products(self) -> None:
        """Always, also after an error: the worker's files (trajectory, map)."""


def run_worker(worker: Worker, sub: BusSubscriber, stop, state=None) -> None:
    """The run loop every worker shares: live until ``stop`` is set, then drain, then finish. ``state``
    (a callable) is called about once a second while live: the worker's state onto the bus. As often, the
    C heap's free pages go back to the system (``release_free_heap``): the arrays a worker frees every
    frame would otherwise stay with it."""
    last_state = 0.0
    while not stop.is_set():
        msg = sub.receive(timeout_ms=50)
        # Everything that has come, into the worker's own queues, before the next piece of work: left in the
        # socket, a backlog would grow without bound (the worker bounds its queues, dropping counted).
        received = 0
        while msg is not None:
            worker.handle(decode(msg), live=True)
            received += 1
            msg = sub.receive(timeout_ms=0) if received < MAX_BATCH else None
        worker.lost_on_bus(sub.missed_by_topic())
        worker.step()
        if time.monotonic() - last_state >= 1.0:
            if state is not None:
                state()
            release_free_heap()
            last_state = time.monotonic()
    now = time.monotonic()
    deadline, quiet_until = now + worker.drain_max_s, now + worker.drain_quiet_s
    while (now := time.monotonic()) < deadline and now < quiet_until:
        msg = sub.receive(timeout_ms=100)
        if msg is None:
            continue
        quiet_until = time.monotonic() + worker.drain_quiet_s
        message = decode(msg)
        if worker.drained(message):
            # The end marker comes on an endpoint of its own: what the drivers sent before it may still be
            # queued on theirs, and is handled rather than left in the socket.
            while (msg := sub.receive(timeout_ms=0)) is not None:
                worker.handle(decode(msg), live=False)
            break
        worker.handle(message, live=False)
    worker.lost_on_bus(sub.missed_by_topic())
    worker.finish()


@dataclasses.dataclass
class WorkerSpec:
    """A worker for the daemon: ``worker`` (a Worker subclass) built with ``config`` in a process named
    ``role`` that publishes on ``endpoint``. ``upstream``: other workers wait on what it publishes (niced
    less than they are: ``acquisition.processes.worker_nice``)."""

    role: str
    worker: type
    config: Any
    endpoint: str = dataclasses.field(default_factory=bus_endpoint)
    upstream: bool = False


def worker_process(spec: WorkerSpec, driver_endpoints: list[str], stop, frame_endpoints: list[str] = ()) -> None:
    """A worker's process: subscribe to the drivers (and the worker's own extra endpoints), run, write.
    ``frame_endpoints`` (the radars') get a short queue: a worker that falls behind loses frames (counted,
    ``bus_lost`` in its state), not the machine's memory."""
    become_child(spec.role, background=True, upstream=spec.upstream)
    pub = BusPublisher(spec.endpoint)
    worker = spec.worker(spec.config, pub)
    # Subscribed before warming up: what the drivers send meanwhile queues, and is handled in order after.
    sub = BusSubscriber([*driver_endpoints, *worker.endpoints], topics=worker.topics,
                        high_water_marks=dict.fromkeys(frame_endpoints, FRAME_QUEUE))
    warm_up_s = [0.0]

    def state(warm: bool = True) -> None:
        counters = {**worker.counters(), "bus_lost": sub.missed}
        pub.send(WorkerState(spec.role, warm, warm_up_s[0], counters, worker.calibration(), time.time_ns()))

    try:
        state(warm=False)
        t0 = time.monotonic()
        worker.warm_up()
        warm_up_s[0] = time.monotonic() - t0
        log.info("%s: warm after %.1f s", spec.role, warm_up_s[0])
        state()
        run_worker(worker, sub, stop, state)
        time.sleep(0.2)  # let the subscribers take the last messages before the socket closes
    finally:
        worker.write_products()
        pub.close()
        sub.close()
