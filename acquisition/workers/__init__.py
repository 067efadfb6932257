"""Worker processes of ``sarbot run``: what consumes the drivers' data live (odometry, strip map).

Every worker has the same run loop (``run_worker``): subscribe to its topics, handle each message while
live, drain what the drivers send on their way out, finish (the last results onto the bus), and write its
products whatever happened. A worker is described by a ``WorkerSpec``; the daemon starts each in a
process of its own with ``worker_process``.

Stopping is bounded. The daemon gives its workers ``worker_stop_timeout_s`` after the stop; a worker's own
budgets (draining, ``finish``) are cut to fit in it less the time it keeps for writing (``stop_budgets``). A
worker still running then gets SIGTERM: it hurries (``Worker.hurried``), that is, at its next chance (between
two imaging calls, two refocused tiles) it leaves its queue, skips what is left of draining and finishing,
and writes its products with what it has, saying so in them; the daemon kills it only if it has not exited
``worker_hurry_timeout_s`` later. The hurry is a flag looked at between calls: a call into a compiled kernel
cannot be interrupted (numba's native code runs without the interpreter, whose signal handler waits for it to
return), nor is a call left halfway (numba compiling on a cold cache). The second grace is for the call in
progress; one that outlasts it still ends in a kill.
"""

from __future__ import annotations

import dataclasses
import logging
import signal
import time
from typing import Any

from ..bus import FRAME_QUEUE, BusPublisher, BusSubscriber
from ..messages import BusMessage, WorkerState, decode
from ..processes import become_child, bus_endpoint, release_free_heap

log = logging.getLogger(f"sarbot.{__name__}")

#: Most messages a worker takes from its socket between two steps.
MAX_BATCH = 1000
#: Hurried, how long a worker takes in what is already in its socket (the frames that queued behind the call
#: the hurry waited for), for it to count them as left out, s.
HURRY_TAKE_S = 0.5


class Worker:
    """The skeleton a worker fills in. Built in its process as ``cls(config, publisher)``.

    ``topics`` (prefixes) and ``endpoints`` (besides the drivers') say what it subscribes to.
    Draining at the end lasts until ``drained(message)`` says the last expected message came, until
    nothing came for ``drain_quiet_s``, or for at most ``drain_max_s``.

    ``finish_max_s``: the most ``finish`` may take (0: it does not take long); ``write_reserve_s``: what is kept
    for ``write_products`` within the daemon's stop timeout. ``hurried`` is set (by SIGTERM, ``worker_process``)
    when the worker must write what it has now: ``handle``, ``step`` and ``finish`` look at it between their
    pieces of work.
    """

    topics: list[str] = []
    endpoints: list[str] = []
    drain_quiet_s: float = 0.5
    drain_max_s: float = 10.0
    finish_max_s: float = 0.0
    write_reserve_s: float = 2.0
    hurried: bool = False

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
        """After draining: the last results onto the bus, within ``finish_max_s``; hurried, only what is cheap."""

    def write_products(self) -> None:
        """Always, also after an error or when hurried: the worker's files (trajectory, map)."""


def stop_budgets(worker: Worker | type, stop_timeout_s: float) -> tuple[float, float]:
    """The draining and finishing budgets (s) of ``worker`` (a Worker or its class) within the daemon's
    ``stop_timeout_s`` (s): its own ``drain_max_s`` and ``finish_max_s`` where they fit with
    ``write_reserve_s`` left for writing, else both scaled down alike to fit (0 with no room at all)."""
    wanted = worker.drain_max_s + worker.finish_max_s
    room = max(stop_timeout_s - worker.write_reserve_s, 0.0)
    scale = min(1.0, room / wanted) if wanted > 0 else 1.0
    return worker.drain_max_s * scale, worker.finish_max_s * scale


def stop_needs_s(worker: Worker | type) -> float:
    """The longest ``worker``'s stop takes with its own budgets: draining, finishing, writing (s)."""
    return worker.drain_max_s + worker.finish_max_s + worker.write_reserve_s


def run_worker(worker: Worker, sub: BusSubscriber, stop, state=None) -> None:
    """The run loop every worker shares: live until ``stop`` is set, then drain, then finish. ``state``
    (a callable) is called about once a second while live: the worker's state onto the bus. As often, the
    C heap's free pages go back to the system (``release_free_heap``): the arrays a worker frees every
    frame would otherwise stay with it. A hurried worker (``Worker.hurried``) leaves the loop or the draining at
    once, and finishes hurried."""
    last_state = 0.0
    while not stop.is_set() and not worker.hurried:
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
    while (now := time.monotonic()) < deadline and now < quiet_until and not worker.hurried:
        msg = sub.receive(timeout_ms=100)
        if msg is None:
            continue
        quiet_until = time.monotonic() + worker.drain_quiet_s
        message = decode(msg)
        if worker.drained(message):
            # The end marker comes on an endpoint of its own: what the drivers sent before it may still be
            # queued on theirs, and is handled rather than left in the socket.
            while not worker.hurried and (msg := sub.receive(timeout_ms=0)) is not None:
                worker.handle(decode(msg), live=False)
            break
        worker.handle(message, live=False)
    if worker.hurried:
        # Left in the socket, they would be neither received nor lost: a map's counts would not add up.
        until = time.monotonic() + HURRY_TAKE_S
        while time.monotonic() < until and (msg := sub.receive(timeout_ms=0)) is not None:
            worker.handle(decode(msg), live=False)
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


def worker_process(spec: WorkerSpec, driver_endpoints: list[str], stop, frame_endpoints: list[str] = (),
                   stop_timeout_s: float | None = None) -> None:
    """A worker's process: subscribe to the drivers (and the worker's own extra endpoints), run, write.
    ``frame_endpoints`` (the radars') get a short queue: a worker that falls behind loses frames (counted,
    ``bus_lost`` in its state), not the machine's memory. ``stop_timeout_s``: the daemon's
    ``worker_stop_timeout_s``, which the worker's budgets are cut to fit (``stop_budgets``; None: its own).

    SIGTERM hurries the worker (``Worker.hurried``): the daemon's second, last notice before it kills it,
    and what the kernel sends when the daemon dies (``processes.die_with_parent``), so an orphaned worker
    writes what it has and exits too. A second SIGTERM changes nothing: the worker is writing already."""
    become_child(spec.role, background=True, upstream=spec.upstream)
    pub = BusPublisher(spec.endpoint)
    worker = spec.worker(spec.config, pub)
    if stop_timeout_s is not None:
        worker.drain_max_s, worker.finish_max_s = stop_budgets(worker, stop_timeout_s)

    def hurry(signum, frame) -> None:
        # Only a flag (no logging, whose lock the interrupted code may hold): the handler runs between two
        # bytecodes of whatever the worker does, and the worker leaves its work at a point of its own choosing,
        # where its counts add up.
        worker.hurried = True

    signal.signal(signal.SIGTERM, hurry)
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
        if worker.hurried:
            log.warning("%s: hurried (SIGTERM) at the stop: writing its products with what it has", spec.role)
        worker.write_products()
        pub.close()
        sub.close()
