"""The message bus: ZeroMQ multipart ``[topic, msgpack header, raw array buffers...]`` (see docs/bus.md).

Every header carries a per-topic sequence number, the sensor time and the host time, plus the dtype and
shape of each array, so arrays travel without copies or pickling and every consumer can count what it
missed. PUB/SUB drops messages when a slow subscriber's queue is full; those drops are never silent: the
receiver sees the sequence gap, counts it, and reports it (the recorder writes it to /events).
"""

from __future__ import annotations

import dataclasses
import os
import time
import uuid
from collections import defaultdict

import msgpack
import numpy as np
import zmq

DEFAULT_ENDPOINT = "tcp://127.0.0.1:5560"


@dataclasses.dataclass
class Message:
    topic: str
    seq: int
    sensor_time_ns: int
    host_time_ns: int
    header: dict
    arrays: list[np.ndarray]


#: A topic the recorder subscribes to and nobody publishes: a driver that sees this subscription knows the
#: recorder listens to it (see ``BusPublisher.wait_for_subscriber``). ZeroMQ drops what a publisher sends
#: before a subscriber's subscription has reached it, without a trace.
RECORDER_LISTENING = "recorder/listening"

#: Radar frames (0.7 MB each at the reference waveform) queued per slow subscriber on either side of a
#: connection to a worker before ZeroMQ drops them (counted as bus loss by the worker): a worker that
#: cannot keep up loses frames, not the machine's memory. The recorder's side keeps the default.
FRAME_QUEUE = 50


class BusPublisher:
    """Publishes on one endpoint; numbers messages per topic."""

    def __init__(self, endpoint: str = DEFAULT_ENDPOINT, context: zmq.Context | None = None, bind: bool = True,
                 high_water_mark: int = 10_000, watch_subscriptions: bool = False):
        """``watch_subscriptions``: an XPUB socket (a PUB that hears its subscribers' subscriptions), for
        ``wait_for_subscriber``."""
        self.context = context or zmq.Context.instance()
        self.socket = self.context.socket(zmq.XPUB if watch_subscriptions else zmq.PUB)
        self.subscriptions: set[str] = set()
        self.socket.setsockopt(zmq.SNDHWM, high_water_mark)
        self.socket.setsockopt(zmq.LINGER, 1000)
        try:
            (self.socket.bind if bind else self.socket.connect)(endpoint)
        except zmq.ZMQError:
            self.socket.close(0)
            raise
        self.endpoint = self.socket.getsockopt_string(zmq.LAST_ENDPOINT) if bind else endpoint
        self._seq: dict[str, int] = defaultdict(int)
        # Several publishers may send one topic (every driver sends "event"): sequences are per publisher.
        self.publisher_id = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"

    def publish(self, topic: str, sensor_time_ns: int, arrays: list[np.ndarray] = (), **fields) -> int:
        """Send one message; returns its sequence number. Arrays are sent from their own memory."""
        seq = self._seq[topic]
        self._seq[topic] = seq + 1
        arrays = [np.ascontiguousarray(a) for a in arrays]
        header = {"seq": seq, "pub": self.publisher_id, "sensor_time_ns": int(sensor_time_ns), "host_time_ns": time.time_ns(),
                  "arrays": [[a.dtype.str, list(a.shape)] for a in arrays], **fields}
        # An empty array (a scan with no detection) is an empty frame: a memoryview of one cannot be cast.
        parts = [topic.encode(), msgpack.packb(header, use_bin_type=True),
                 *[memoryview(a).cast("B") if a.size else b"" for a in arrays]]
        self.socket.send_multipart(parts, copy=False)
        return seq

    def wait_for_subscriber(self, topic: str, timeout_s: float, stop=None) -> bool:
        """Wait until a subscriber has subscribed to ``topic`` (or ``timeout_s`` passes, or ``stop`` is set);
        True if one has. Needs ``watch_subscriptions``. A driver waits so for the recorder
        (``RECORDER_LISTENING``) before it publishes: its socket buffer (a radar's UDP socket) keeps what
        arrives meanwhile, where messages published before would be dropped unseen."""
        deadline = time.monotonic() + timeout_s
        while topic not in self.subscriptions:
            left_ms = int((deadline - time.monotonic()) * 1e3)
            if left_ms <= 0 or (stop is not None and stop.is_set()):
                return False
            self._hear_subscriptions(min(left_ms, 100))
        return True

    def has_subscriber(self, topic: str) -> bool:
        """Whether a subscriber has subscribed to ``topic`` by now, without waiting. Needs
        ``watch_subscriptions``."""
        while topic not in self.subscriptions and self._hear_subscriptions(0):
            pass
        return topic in self.subscriptions

    def _hear_subscriptions(self, timeout_ms: int) -> bool:
        """Take one (un)subscription note off the socket, waiting up to ``timeout_ms``; whether one came."""
        if not self.socket.poll(timeout_ms, zmq.POLLIN):
            return False
        note = self.socket.recv()
        if note[:1] == b"\x01":
            self.subscriptions.add(note[1:].decode(errors="replace"))
        elif note[:1] == b"\x00":
            self.subscriptions.discard(note[1:].decode(errors="replace"))
        return True

    def send(self, message) -> int:
        """Publish a typed message (``acquisition.messages``); returns its sequence number."""
        parts = message.to_parts()
        return self.publish(parts.topic, parts.sensor_time_ns, parts.arrays, **parts.fields)

    def close(self) -> None:
        self.socket.close()


@dataclasses.dataclass
class TopicStats:
    received: int = 0
    missed: int = 0
    gaps: int = 0
    restarts: int = 0  # the sequence went back to 0: the publisher restarted


class BusSubscriber:
    """Subscribes to topics (prefixes) on one or more endpoints and checks every topic's sequence."""

    def __init__(self, endpoints: str | list[str] = DEFAULT_ENDPOINT, topics: list[str] = ("",),
                 context: zmq.Context | None = None, high_water_mark: int = 10_000,
                 high_water_marks: dict[str, int] | None = None, counted_from_start: tuple[str, ...] = ()):
        """``high_water_marks``: a queue length of its own for some endpoints (messages; beyond it ZeroMQ
        drops, and the sequence gap is counted).

        ``counted_from_start``: topic prefixes whose publishers this subscriber must hear from their first
        message (the recorder's sensor data: the drivers wait for it): a first sequence number above 0 is
        counted as that many messages missed. Others (a subscriber that joins a running bus) start counting
        at the first message they get.

        Endpoints with different queue lengths get sockets of their own: ZeroMQ (since 4.2) applies a
        socket's ZMQ_RCVHWM to every connection it has, so a length set for one endpoint and another set
        for the next would leave the first with the second's (a worker's 50-frame queue grew without
        bound, 0.7 MB a frame, once the IMU's 10,000 was set after it). Messages are taken from ready
        sockets in turn."""
        self.context = context or zmq.Context.instance()
        by_hwm: dict[int, list[str]] = defaultdict(list)
        for e in [endpoints] if isinstance(endpoints, str) else endpoints:
            by_hwm[(high_water_marks or {}).get(e, high_water_mark)].append(e)
        self.sockets: list[zmq.Socket] = []
        self.poller = zmq.Poller()
        for hwm, group in by_hwm.items():
            sock = self.context.socket(zmq.SUB)
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.RCVHWM, hwm)  # before any connect: the one length of all its connections
            for t in topics:
                sock.setsockopt(zmq.SUBSCRIBE, t.encode())
            for e in group:
                sock.connect(e)
            self.sockets.append(sock)
            self.poller.register(sock, zmq.POLLIN)
        self.counted_from_start = tuple(counted_from_start)
        self._next = 0  # the socket to look at first, in turn: none starves the others
        self.stats: dict[str, TopicStats] = defaultdict(TopicStats)
        self._expected: dict[tuple[str, str], int] = {}  # (publisher, topic) -> next sequence number

    def receive(self, timeout_ms: int | None = None) -> Message | None:
        """The next message, or None after ``timeout_ms``; arrays are views on the received frames."""
        parts = self._recv_ready()
        if parts is None:
            if not self.poller.poll(timeout_ms if timeout_ms is not None else -1):
                return None
            parts = self._recv_ready()
            if parts is None:
                return None
        topic = bytes(parts[0].buffer).decode()
        header = msgpack.unpackb(parts[1].buffer, raw=False)
        arrays = [np.frombuffer(p.buffer, dtype=np.dtype(dt)).reshape(shape)
                  for p, (dt, shape) in zip(parts[2:], header.get("arrays", []))]
        self._check(topic, header.get("pub", ""), int(header["seq"]))
        return Message(topic, header["seq"], header["sensor_time_ns"], header["host_time_ns"], header, arrays)

    def _recv_ready(self):
        """One whole message from the first socket with one waiting, starting after the last one served."""
        n = len(self.sockets)
        for k in range(n):
            i = (self._next + k) % n
            try:
                parts = self.sockets[i].recv_multipart(flags=zmq.NOBLOCK, copy=False)
            except zmq.Again:
                continue
            self._next = (i + 1) % n
            return parts
        return None

    @property
    def missed(self) -> int:
        """Messages lost on the bus so far, over all topics (sequence gaps)."""
        return sum(st.missed for st in self.stats.values())

    def missed_by_topic(self) -> dict[str, int]:
        """Messages lost on the bus so far, per topic with any lost."""
        return {topic: st.missed for topic, st in self.stats.items() if st.missed}

    def _check(self, topic: str, publisher: str, seq: int) -> None:
        st = self.stats[topic]
        st.received += 1
        key = (publisher, topic)
        expected = self._expected.get(key)
        if expected is None and seq == 0 and any(t == topic for _, t in self._expected):
            st.restarts += 1  # a new publisher of a topic already heard: a restarted driver
        if expected is None and seq > 0 and topic.startswith(self.counted_from_start):
            expected = 0  # what it sent before this subscriber heard it is lost to it
        if expected is not None and seq > expected:
            st.gaps += 1
            st.missed += seq - expected
        self._expected[key] = seq + 1

    def close(self) -> None:
        for sock in self.sockets:
            sock.close()
