"""UDP reception the way a radar driver needs it: receive time stamps (the kernel's, and the network card's
where it can: ``drivers.radar.timestamping``), the kernel's drop counter, a large receive buffer (Linux socket
options, numeric where Python does not name them), and few wake-ups.

A radar sends a frame as a burst of hundreds of datagrams, and a receiver faster than the sender finds
the socket empty after almost every one: woken per datagram (5,600 times a second per driver in the
four-radar soak), it spent more on waking than on the data. So an empty socket is looked at again only
after ``coalesce_s`` (as a network card coalesces interrupts): the datagrams that came meanwhile are taken
in one go. The kernel's receive timestamps keep every datagram's time exact; a frame is published at
most ``coalesce_s`` later.

Every datagram's host time is the kernel's software stamp (CLOCK_REALTIME), whatever the card does: latency,
replay and the IMU's trigger estimate measure against the host's clock. With hardware stamps the card's stamp
(its PTP hardware clock) comes beside it (``last_nic_ns``); a datagram the card left unstamped is counted
(``nic_unstamped``) and has none.

Where Linux has it (5.0+), the socket takes UDP GRO (generic receive offload, ``UDP_GRO``): the kernel hands
over many datagrams of one flow and one size in one buffer, with their size in a control message, and
``receive_segments`` returns such a batch in one system call (a radar driver no longer pays one ``recvmsg``
per datagram; 10,000 a second each). A batch carries one kernel stamp, its first datagram's (GRO keeps the
first packet's stamps), so a datagram inside a batch is stamped early by at most the batch's span: 64
datagrams of 1.5 kB are 0.8 ms on 1 Gbit/s; over loopback from ``UdpSender`` nothing, since the kernel stamps a
segmented send once and a socket without GRO sees the same stamp on every datagram cut from it.
"""

from __future__ import annotations

import errno
import logging
import select
import socket
import struct
import sys
import time

from .timestamping import HARDWARE_FLAGS, SCM_TIMESTAMPING, SCM_TIMESTAMPING_MIN_BYTES, SO_TIMESTAMPING, SOFTWARE_FLAGS, \
    StampChoice, choose_receive_stamps, parse_scm_timestamping, software_stamp_ns

SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
SOL_UDP = getattr(socket, "SOL_UDP", 17)
#: Linux's UDP generic receive offload (5.0+): many datagrams of one flow and size in one receive.
UDP_GRO = getattr(socket, "UDP_GRO", 104)
#: The receive buffer for a batch: a GRO batch is at most 64 kB on IPv4 today; room for more, and a batch
#: that still does not fit is counted (``truncated_batches``) instead of being taken for whole.
BATCH_BUFFER_BYTES = 4 * 65536

log = logging.getLogger(f"sarbot.{__name__}")


def usable_rcvbuf_bytes(reported_bytes: int) -> int:
    """The receive buffer for data that getsockopt's SO_RCVBUF stands for: Linux reports twice what was
    granted (the other half is its bookkeeping), other systems what was granted."""
    return reported_bytes // 2 if sys.platform.startswith("linux") else reported_bytes


class UdpReceiver:
    """A bound UDP socket returning (payload, kernel receive time ns, kernel drops so far)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, rcvbuf_bytes: int = 32 << 20, timeout_s: float = 0.1,
                 accept_from: str | None = None, coalesce_s: float = 0.002, receive_stamps: str = "auto",
                 gro: bool = True):
        """``accept_from``: the only source address whose datagrams are taken; others are counted
        (``foreign_source``, per receive: a GRO batch is one flow, so one source) and dropped. None takes every sender (loopback, a single radar).
        ``coalesce_s``: how long an empty socket is left before it is looked at again (0: at once).
        ``receive_stamps``: "auto", "hardware" or "software" (``timestamping.choose_receive_stamps``; "hardware"
        where the interface cannot is a SarbotError naming it and what it lacks); the choice is ``stamps``.
        ``gro``: ask for UDP GRO (batches of datagrams, ``receive_segments``); ``self.gro`` says whether the
        kernel took it (False where it refused: one datagram per receive, as before)."""
        #: Which stamps, on which interface, and why (``timestamping.StampChoice``).
        self.stamps: StampChoice = choose_receive_stamps(host, accept_from, receive_stamps)
        self.hardware = self.stamps.source == "hardware"
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # No SO_REUSEADDR: with it a second socket (another process, another local user) could bind the
        # same port and take the radar's datagrams.
        try:  # as root the buffer may exceed net.core.rmem_max
            self.sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, rcvbuf_bytes)
        except OSError:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf_bytes)
        self.rcvbuf_bytes = self.sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        self.rcvbuf_asked_bytes = rcvbuf_bytes
        #: What to say when the kernel granted less buffer than asked (None when it granted all).
        self.rcvbuf_short: str | None = None
        granted = usable_rcvbuf_bytes(self.rcvbuf_bytes)
        if granted < rcvbuf_bytes:
            self.rcvbuf_short = (f"UDP receive buffer {granted / 1e6:.1f} MB of {rcvbuf_bytes / 1e6:.1f} MB asked "
                                 "(net.core.rmem_max caps it; sarbot install-unit stages /etc/sysctl.d/60-sarbot.conf): "
                                 "a burst of frames may overflow it")
            log.warning("%s", self.rcvbuf_short)
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPING, HARDWARE_FLAGS if self.hardware else SOFTWARE_FLAGS)
        self.sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
        #: Whether the socket takes UDP GRO: batches of datagrams in one receive (``receive_segments``).
        self.gro = False
        if gro and sys.platform.startswith("linux"):
            try:
                self.sock.setsockopt(SOL_UDP, UDP_GRO, 1)
                self.gro = True
            except OSError:  # a kernel before 5.0: one datagram per receive
                pass
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise OSError(exc.errno, f"cannot listen on UDP {host}:{port}: {exc.strerror}") from None
        # Non-blocking: a waiting datagram costs one system call, not a poll and a receive.
        self.sock.setblocking(False)
        self._poll = select.poll()
        self._poll.register(self.sock, select.POLLIN)
        self.timeout_ms = int(timeout_s * 1e3)
        self.coalesce_s = coalesce_s
        self.address = self.sock.getsockname()
        self.kernel_drops = 0
        self.accept_from = accept_from
        self.foreign_source = 0
        #: The card's stamp (its PTP hardware clock, ns) of the datagram ``receive`` returned last; 0 where none.
        self.last_nic_ns = 0
        #: Datagrams the card left unstamped while hardware stamps are in use (timed by the kernel alone); a
        #: batch the card left unstamped counts all its datagrams.
        self.nic_unstamped = 0
        #: Batches larger than the receive buffer (their tail lost; none expected: see BATCH_BUFFER_BYTES).
        self.truncated_batches = 0
        self._buffer = bytearray(BATCH_BUFFER_BYTES)
        self._view = memoryview(self._buffer)
        self._pending: list[bytes] = []  # the rest of a batch ``receive`` hands out one by one
        self._pending_stamp = (0, 0)

    def receive(self, max_bytes: int = 65536) -> tuple[bytes, int, int] | None:
        """One datagram ``(payload, kernel receive time ns, kernel drops so far)``, or None on timeout (or for
        a datagram from a source not accepted). The datagrams of a GRO batch come one per call, each with the
        batch's stamp. ``max_bytes``: the most of a datagram returned (longer ones are cut)."""
        if self._pending:
            t_ns, drops = self._pending_stamp
            return self._pending.pop(), t_ns, drops
        got = self.receive_segments()
        if got is None:
            return None
        view, segment_bytes, t_ns, drops = got
        if len(view) <= segment_bytes:
            return bytes(view[:max_bytes]), t_ns, drops
        segments = [bytes(view[o:o + min(segment_bytes, max_bytes)]) for o in range(0, len(view), segment_bytes)]
        self._pending = segments[:0:-1]  # popped from the end: in order
        self._pending_stamp = (t_ns, drops)
        return segments[0], t_ns, drops

    def receive_segments(self) -> tuple[memoryview, int, int, int] | None:
        """One batch of datagrams: ``(buffer, segment_bytes, t_ns, kernel_drops)``, or None on timeout (or
        for a batch from a source not accepted).

        ``buffer`` holds the datagrams back to back, each ``segment_bytes`` long but the last, which may be
        shorter; a datagram the kernel did not batch (no GRO, another size, a plain send) is a batch of one,
        ``segment_bytes == len(buffer)``. ``t_ns`` is the kernel's receive stamp of the batch (host clock,
        ns; its first datagram's), ``kernel_drops`` the socket's drop counter so far; with GRO the kernel
        counts a dropped batch once (checked on Linux 6.18), so the counter counts drops, not datagrams.
        With hardware stamps ``last_nic_ns`` is the card's stamp of the batch's first datagram.

        ``buffer`` is a view of the receiver's one buffer, overwritten by the next receive: be done with it
        (or copy what must outlive it) before calling again. Not to be mixed with ``receive`` while that
        still holds the rest of a batch."""
        try:
            n, ancdata, flags, source = self.sock.recvmsg_into((self._buffer,), 256)
        except BlockingIOError:
            if self.coalesce_s > 0:
                time.sleep(self.coalesce_s)
            if not self._poll.poll(self.timeout_ms):
                return None
            try:
                n, ancdata, flags, source = self.sock.recvmsg_into((self._buffer,), 256)
            except BlockingIOError:
                return None
        if self.accept_from is not None and source[0] != self.accept_from:
            self.foreign_source += 1
            return None
        t_ns = nic_ns = 0
        segment_bytes = n
        for level, kind, value in ancdata:  # per batch: the common case first
            if kind == SCM_TIMESTAMPING and level == socket.SOL_SOCKET and len(value) >= SCM_TIMESTAMPING_MIN_BYTES:
                if self.hardware:
                    t_ns, _, nic_ns = parse_scm_timestamping(value)
                else:
                    t_ns = software_stamp_ns(value)
            elif level == SOL_UDP and kind == UDP_GRO:  # an int on Linux; a u16 where the kernel says 2 bytes
                segment_bytes = struct.unpack_from("=H" if len(value) == 2 else "=i", value)[0]
            elif level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(value) >= 4:
                self.kernel_drops = struct.unpack_from("I", value)[0]
        if flags & socket.MSG_TRUNC:
            self.truncated_batches += 1
        if not 0 < segment_bytes <= n:  # a batch of one (or an empty datagram)
            segment_bytes = n
        if self.hardware:
            self.last_nic_ns = nic_ns
            self.nic_unstamped += 0 if nic_ns else -(-n // segment_bytes) if n else 1
        return self._view[:n], segment_bytes, t_ns, self.kernel_drops

    def close(self) -> None:
        self.sock.close()


#: Linux's UDP segmentation offload (``UDP_SEGMENT``, Linux 4.18): one send carries many datagrams of one size.
UDP_SEGMENT = getattr(socket, "UDP_SEGMENT", 103)
#: The most one send with ``UDP_SEGMENT`` carries: 64 datagrams (``UDP_MAX_SEGMENTS`` of the oldest kernels
#: that have it) and an IPv4 datagram's 65,507 bytes.
MAX_SEGMENTS = 64
MAX_SEGMENTED_BYTES = 65_507
#: What a kernel without it, or a route that cannot take it, answers a segmented send with.
SEGMENTATION_REFUSED = (errno.EINVAL, errno.ENOPROTOOPT, errno.EIO, errno.EOPNOTSUPP)


class UdpSender:
    """Sends a frame's datagrams (``registry.PackedDatagrams``) to one address in as few system calls as
    Linux allows: up to ``MAX_SEGMENTS`` datagrams of one size in one ``sendmsg`` with ``UDP_SEGMENT``,
    which the kernel cuts into exactly the datagrams that one ``sendto`` each would send (the receiver
    cannot tell). The emulated radars of replay send 10,000 datagrams a second each; one system call and
    one Python object per datagram cost more than the rest of the emulation. Where the kernel or the route
    refuses segmentation (an old kernel, a card that cannot checksum it), every datagram goes by its own
    ``sendto``, as before; ``segmented`` says which."""

    def __init__(self, sndbuf_bytes: int = 8 << 20, segmented: bool = hasattr(socket, "SOL_UDP")):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, sndbuf_bytes)
        #: Whether sends are segmented (False from the first the kernel refused on).
        self.segmented = segmented and sys.platform.startswith("linux")

    def send(self, datagrams, address) -> int:
        """Send ``datagrams`` (``PackedDatagrams``) to ``address``; returns how many datagrams went."""
        data, size = memoryview(datagrams.data), datagrams.size
        if not len(data):
            return 0
        per_send = max(1, min(MAX_SEGMENTS, MAX_SEGMENTED_BYTES // size)) * size
        start = 0
        if self.segmented:
            option = [(SOL_UDP, UDP_SEGMENT, struct.pack("=H", size))]
            try:
                for start in range(0, len(data), per_send):
                    self.sock.sendmsg([data[start:start + per_send]], option, 0, address)
                start = len(data)
            except OSError as exc:  # nothing of the refused send went out: it and the rest go one by one
                if exc.errno not in SEGMENTATION_REFUSED:
                    raise
                log.info("UDP segmentation refused (%s): sending datagram by datagram", exc)
                self.segmented = False
        for offset in range(start, len(data), size):
            self.sock.sendto(data[offset:offset + size], address)
        return datagrams.count

    def sendto(self, datagram: bytes, address) -> None:
        """One datagram, as it is."""
        self.sock.sendto(datagram, address)

    def close(self) -> None:
        self.sock.close()
