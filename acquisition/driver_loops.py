"""The device drivers' loops and the processes that run them: radar (UDP -> frames -> bus), IMU (serial ->
timed samples -> bus) and CAN (python-can -> frames -> bus).

Each loop runs until its ``stop`` event is set; the daemon runs each in a process of its own
(``radar_process``, ``imu_process``, ``can_process``), tests may run them in threads. This module and
what it imports stay free of h5py and matplotlib: a driver process only moves bytes.
"""

from __future__ import annotations

import logging
import os
import threading
import time

from drivers.can_driver import CanConfig, CanDriver
from drivers.imu import ImuDriver
from drivers.radar.link import RadarLink
from drivers.radar.stream import RadarStream, feed_segments, trouble
from drivers.radar.timestamping import CardFrameTimes
from drivers.radar.udp import UdpReceiver
from imaging.core.errors import SarbotError
from imaging.core.waveform import Waveform

from .bus import FRAME_QUEUE, RECORDER_LISTENING, BusPublisher, BusSubscriber
from .messages import CanBatch, Event, ImuBatch, RadarFrameMessage, RadarImuBatch, Trigger
from .processes import become_child

log = logging.getLogger(f"sarbot.{__name__}")

#: With hardware stamps: how many datagrams' card stamps are kept, by host stamp, for the frames they end
#: (a frame completes at most a reorder window after its last datagram).
NIC_STAMPS_KEPT = 65536


class CounterChanges:
    """Which counters rose since last asked, as an event's text ("crc_errors +2, resyncs +1")."""

    def __init__(self, counters: dict[str, int] | None = None):
        self.last = dict(counters or {})

    def since_last(self, counters: dict[str, int]) -> str | None:
        rises = {k: v - self.last.get(k, 0) for k, v in counters.items() if v != self.last.get(k, 0)}
        self.last = dict(counters)
        return ", ".join(f"{k} +{v}" for k, v in rises.items()) if rises else None


def radar_driver_loop(receiver: UdpReceiver, radar: str, stream: RadarStream, pub: BusPublisher,
                      stop: threading.Event, report_every_s: float = 1.0) -> RadarStream:
    """Receive datagrams, reassemble frames with ``stream``, publish each frame; wire trouble and kernel
    drops are published as events. With hardware receive stamps each frame carries the card's stamp of its
    last datagram (``nic_receive_ns``) beside the kernel's, and a stream whose frames are timed by their
    receipt (``times_by_receipt``: the DCA1000) takes its frame times from the card's stamps
    (``timestamping.CardFrameTimes``), said once in /events. Returns the stream.

    A receiver with ``receive_segments`` (``UdpReceiver``) is read a batch at a time (UDP GRO: up to 64
    datagrams in one system call) and the batch goes to the stream in one ``feed_segments``; every datagram of
    a batch has the batch's stamps, its first datagram's. A frame's ``receive_ns`` is so up to a batch's span
    early (64 datagrams of 1.5 kB: 0.8 ms on 1 Gbit/s; none over loopback), and a stream timed by receipt
    would have its frame times as early: ``radar_process`` gives such a stream a receiver without GRO (one
    datagram per receive, each stamped on its own). A receiver with only ``receive`` gives batches of one.
    With GRO the kernel's drop counter counts dropped batches (the event says "receive(s)")."""
    def counted() -> dict[str, int]:
        return {**trouble(stream.counters), "foreign_source": receiver.foreign_source}

    changes = CounterChanges(counted())
    last_report = time.monotonic()
    kernel_drops = 0
    hardware = getattr(receiver, "hardware", False)
    nic_of: dict[int, int] = {}  # host stamp -> card stamp of the recent datagrams (hardware stamps only)
    card_times = CardFrameTimes() if hardware and getattr(stream, "times_by_receipt", False) else None
    if card_times is not None:
        pub.send(Event(time.time_ns(), f"radar.{radar}", "info",
                       f"frame times: the network card's stamp of each frame's first datagram ({stream.wire_format} "
                       "frames carry no time of their own)"))
    if getattr(receiver, "rcvbuf_short", None):  # said once; health repeats it
        pub.send(Event(time.time_ns(), f"radar.{radar}", "warning", receiver.rcvbuf_short, condition="receive_buffer"))

    def report(now_ns: int) -> None:
        if text := changes.since_last(counted()):
            pub.send(Event(now_ns, f"radar.{radar}", "warning", text))

    expire = getattr(stream, "expire", None)  # optional in a RadarStream

    def publish(frames) -> None:
        for frame in frames:
            if hardware:
                _card_stamps(frame, nic_of, card_times)
            pub.send(RadarFrameMessage(radar, frame))

    batched = getattr(receiver, "receive_segments", None)
    dropped = "receive(s) (UDP GRO: a batch of datagrams each)" if getattr(receiver, "gro", False) else "datagram(s)"
    while not stop.is_set():
        if batched is not None:
            got = batched()
        elif (one := receiver.receive()) is not None:  # a receiver without batches: each datagram a batch of one
            got = (one[0], len(one[0]), one[1], one[2])
        else:
            got = None
        if got is None and expire is not None:  # the radar quiet: what it left incomplete is passed on
            publish(expire(time.time_ns()))
        if got is not None:
            data, segment_bytes, t_ns, drops = got
            if drops > kernel_drops:
                pub.send(Event(t_ns, f"radar.{radar}", "error",
                               f"kernel dropped {drops - kernel_drops} {dropped} (socket buffer full)"))
                kernel_drops = drops
            if hardware:
                nic_of[t_ns] = receiver.last_nic_ns
                if len(nic_of) > NIC_STAMPS_KEPT:
                    del nic_of[next(iter(nic_of))]
                if card_times is not None:
                    card_times.observe(t_ns, receiver.last_nic_ns)
            frames = feed_segments(stream, data, segment_bytes, t_ns)
            if frames:  # one batch in several ends a frame: the rest cost no more than the feed
                publish(frames)
                if any(not frame.valid for frame in frames):
                    report(t_ns)
        if time.monotonic() - last_report > report_every_s:  # also when only rejected datagrams come
            if expire is not None:
                publish(expire(time.time_ns()))
            report(time.time_ns())
            last_report = time.monotonic()
    publish(stream.flush())
    report(time.time_ns())
    log.debug("radar %s: stream ended; %s", radar, vars(stream.counters))
    return stream


def _card_stamps(frame, nic_of: dict[int, int], card_times: CardFrameTimes | None) -> None:
    """Give a frame the card's stamps: of its last datagram beside the host's, and, for a stream timed by
    receipt, its time (its first datagram's; the frame's time is that datagram's host stamp until now)."""
    frame.nic_receive_ns = nic_of.get(frame.receive_ns, 0)
    if card_times is not None and frame.frame_time_ns:
        frame.frame_time_ns = card_times.frame_time_ns(frame.frame_time_ns, nic_of.get(frame.frame_time_ns, 0))


def imu_role(radar: str | None) -> str:
    """The name of an IMU's driver process and of its events: ``imu`` for the robot's, ``imu.NAME`` for the
    one on radar NAME's mount."""
    return "imu" if radar is None else f"imu.{radar}"


def imu_driver_loop(port: str, pub: BusPublisher, stop: threading.Event, trigger_time_ns: int | None = None,
                    radar_endpoints: list[str] = (), clock_reference=None, report_every_s: float = 1.0,
                    frame_duration_ns: dict[str, int] | None = None, trigger_host_ns: int | None = None,
                    batch_s: float = 0.05, radar: str | None = None) -> None:
    """Read the Xsens IMU on ``port`` and publish batches of samples on the PTP time base, and the trigger.

    The samples are put on PTP time by the hardware trigger (SyncIn), whose PTP time is ``trigger_time_ns``
    or, when not given, the first radar frame's time on ``radar_endpoints`` (the trigger marks the first
    chirp). ``clock_reference`` (shared memory ``[known, trigger_time_ns, trigger_ticks]``, kept by the
    supervisor) survives the process: a driver restarted mid-run takes the reference from it, since the
    IMU marks only one sample. The port may appear late and go away (unplugged, the emulator done): the
    loop waits for it, and says on the bus (into /events) when it is missing, unreadable or lost, and what
    the Xbus parser had to skip (checksum errors, resyncs, packet-counter gaps).

    Should the one packet with the SyncIn mark be lost, the trigger's tick is estimated from the receive
    times and the trigger's host time (``trigger_host_ns``, or the first radar frame's receive time less its
    ``frame_duration_ns``), and an event says so. Samples go out in batches of ``batch_s`` (a message per
    packet would cost the recorder an HDF5 append per sample).

    With ``radar``, the IMU is the one on that radar's own mount: its batches go out as ``RadarImuBatch``,
    and it does not publish the trigger (its SyncIn marks the same trigger as the robot's IMU).

    With no radar to take the trigger's time from (an IMU-only run), the samples are timed on the host clock
    (``ImuDriver.use_host_clock``), the trigger so made is published as ``host_clock`` and an event says so:
    held back for a trigger time that never comes, they were all lost.
    """
    import serial

    source, label = imu_role(radar), "IMU" if radar is None else f"IMU of radar {radar}"
    trigger_ticks = None
    if clock_reference is not None and clock_reference[0]:
        trigger_time_ns, trigger_ticks = int(clock_reference[1]), int(clock_reference[2])
        log.info("%s: clock reference from before the restart: trigger at tick %d", label, trigger_ticks)
    sub = BusSubscriber(list(radar_endpoints), topics=[RadarFrameMessage.TOPIC]) \
        if radar_endpoints and trigger_time_ns is None else None
    trigger_sent = trigger_ticks is not None
    host_clock = trigger_time_ns is None and trigger_ticks is None and not radar_endpoints
    driver = None
    waiting_since, said_missing = time.monotonic(), False
    parser_changes, last_report = CounterChanges(), time.monotonic()
    batch, batch_started = [], time.monotonic()

    def warn(message: str) -> None:
        log.warning("%s: %s", label, message)
        pub.send(Event(time.time_ns(), source, "warning", message))

    def send_batch(samples, drift_ppm) -> None:
        imu_batch = ImuBatch.from_samples(samples, drift_ppm)
        pub.send(imu_batch if radar is None else RadarImuBatch(radar, imu_batch))

    try:
        while not stop.is_set():
            if driver is None:
                if not os.path.exists(port):
                    if not said_missing and time.monotonic() - waiting_since > 2.0:
                        warn(f"{port} does not exist (yet): waiting for it")
                        said_missing = True
                    time.sleep(0.05)
                    continue
                try:
                    driver = ImuDriver(port, trigger_time_ns=trigger_time_ns, trigger_ticks=trigger_ticks,
                                       trigger_host_ns=trigger_host_ns)
                except (serial.SerialException, OSError) as exc:
                    warn(f"cannot open {port}: {exc}; trying again in 1 s")
                    time.sleep(1.0)
                    continue
                parser_changes = CounterChanges()  # a new parser counts from zero
                if host_clock and not trigger_sent:
                    driver.use_host_clock()
                said_missing = True  # it existed: a later loss is said as such ("serial port lost")
            if sub is not None and trigger_time_ns is None:
                # Never wait here: the serial read below is the loop's one wait. A wait for the radar frame
                # kept the IMU's bytes in the port, and the samples read after it were stamped up to 20 ms
                # late, which put the SyncIn estimate a sample late (the frame's own receive stamp is the
                # kernel's, so taking it up a read later costs nothing).
                msg = sub.receive(timeout_ms=0)
                if msg is not None:
                    first = RadarFrameMessage.from_message(msg)
                    trigger_time_ns = first.frame.frame_time_ns
                    trigger_host_ns = first.frame.receive_ns - (frame_duration_ns or {}).get(first.radar, 0)
                    driver.set_trigger_time(trigger_time_ns, trigger_host_ns)
                    # Only the first frame was needed: subscribed, the radar streams would pile up here.
                    sub.close()
                    sub = None
            try:
                samples = driver.read()
            except (serial.SerialException, OSError) as exc:
                warn(f"serial port lost: {exc}")
                driver.close()
                driver = None
                time.sleep(0.2)
                continue
            clock = driver.clock
            if not trigger_sent and clock.trigger_ticks is not None and clock.trigger_time_ns is not None:
                if driver.trigger_estimated:
                    warn(f"no SyncIn mark {driver.syncin_grace_s:g} s after the trigger (its packet lost?): the trigger's "
                         "IMU tick is estimated from the receive times; IMU times are good to a few ms, not to a tick")
                if driver.host_clock:
                    warn("no radar to take the trigger's time from: IMU samples are timed on the host clock (the first "
                         "sample's receive time, CLOCK_REALTIME + TAI-UTC), good to a few ms, not on PTP time")
                if radar is None:
                    # the trigger's own source; ``source`` stays the driver's role, which its events carry
                    trigger_source = "host_clock" if driver.host_clock else (
                        "imu_receive_time" if driver.trigger_estimated else "imu_syncin")
                    pub.send(Trigger(clock.trigger_time_ns, trigger_source))
                trigger_sent = True
                trigger_ticks = clock.trigger_ticks
                if clock_reference is not None:
                    clock_reference[1], clock_reference[2], clock_reference[0] = clock.trigger_time_ns, clock.trigger_ticks, 1
            if samples:
                if not batch:
                    batch_started = time.monotonic()
                batch += samples
            if batch and time.monotonic() - batch_started >= batch_s:
                send_batch(batch, clock.drift_ppm())
                batch = []
            if time.monotonic() - last_report > report_every_s:
                trouble_now = {k: v for k, v in vars(driver.parser.counters).items() if k != "messages"}
                if text := parser_changes.since_last(trouble_now):
                    pub.send(Event(time.time_ns(), source, "warning", text))
                last_report = time.monotonic()
    finally:
        if batch:
            send_batch(batch, driver.clock.drift_ppm() if driver is not None else None)
        if driver is not None:
            driver.close()
        if sub is not None:
            sub.close()


def can_driver_loop(driver: CanDriver, pub: BusPublisher, stop: threading.Event) -> None:
    """Read CAN frames, publish them in batches raw, and each sync-box trigger frame as a trigger."""
    while not stop.is_set():
        frames, triggers = driver.read(timeout_s=0.05)
        for t in triggers:
            pub.send(Trigger(t, "can"))
        if len(frames):
            pub.send(CanBatch(frames.time_ns, frames.arbitration_id, frames.dlc, frames.data))


# -- the processes ------------------------------------------------------------------------------------
#: How long a driver process waits for the recorder to listen before it publishes anyway.
RECORDER_WAIT_S = 10.0


def publisher_heard_by_recorder(endpoint: str, role: str, stop, **kwargs) -> BusPublisher:
    """The driver's publisher, once the recorder has subscribed to it (or after ``RECORDER_WAIT_S``).

    A ZeroMQ publisher drops, unseen, what it sends before a subscriber's subscription has reached it: a radar
    already streaming when ``record`` started lost its first frames (0-3) and nobody counted them. Waiting
    here, the device's own buffer (the UDP socket's, already bound) keeps them. Not for a serial device
    (``PublisherHoldingForRecorder``): opening a serial port throws away what waited in it (pyserial flushes
    the input), and its buffer is a few kilobytes."""
    pub = BusPublisher(endpoint, watch_subscriptions=True, **kwargs)
    if not pub.wait_for_subscriber(RECORDER_LISTENING, RECORDER_WAIT_S, stop) and not stop.is_set():
        log.warning("%s: no recorder listening after %.0f s; publishing anyway", role, RECORDER_WAIT_S)
    return pub


class PublisherHoldingForRecorder:
    """A driver's publisher that sends nothing before the recorder listens: what the driver publishes
    before is held, in order, and sent once the recorder has subscribed (or after ``wait_s``, with a
    warning), so the driver can read its device from the start instead of waiting.

    For the IMU: the SyncIn mark comes in one packet, and the driver opened its port only once the recorder
    listened, which flushed a SyncIn sent before (the run fell back to the receive-time estimate). Holding
    costs memory for at most ``wait_s`` of the device's data (10 s of IMU batches: some 200 messages)."""

    def __init__(self, endpoint: str, role: str, wait_s: float = RECORDER_WAIT_S, **kwargs):
        self.pub = BusPublisher(endpoint, watch_subscriptions=True, **kwargs)
        self.endpoint = self.pub.endpoint
        self.role = role
        self.held: list | None = []  # None once the recorder listens (or the wait is over)
        self.deadline = time.monotonic() + wait_s
        self.wait_s = wait_s

    def send(self, message) -> None:
        if self.held is not None:
            if not self._release():
                self.held.append(message)
                return
        self.pub.send(message)

    def _release(self) -> bool:
        """Send what is held if the recorder listens now or the wait is over; whether it was sent."""
        heard = self.pub.has_subscriber(RECORDER_LISTENING)
        if not heard and time.monotonic() < self.deadline:
            return False
        if not heard:
            log.warning("%s: no recorder listening after %.0f s; publishing anyway", self.role, self.wait_s)
        held, self.held = self.held, None
        for message in held:
            self.pub.send(message)
        return True

    def close(self) -> None:
        """Send what is still held (the recorder may listen by now), then close."""
        if self.held is not None:
            self.deadline = 0.0
            self._release()
        self.pub.close()


def radar_process(link: RadarLink, waveform: Waveform, endpoint: str, stop, bound_port=None) -> None:
    """A radar's driver process: listens on the link, publishes its frames on ``endpoint``. A link on port 0
    binds one the system picks and writes it to ``bound_port`` (a shared integer); restarted, it binds that
    one again, so the sender's address stays right."""
    become_child(link.name, realtime=True)
    stream = link.open_stream(waveform)
    port = (bound_port.value or link.port) if bound_port is not None else link.port
    try:
        # A stream timed by receipt (DCA1000) keeps a stamp per datagram: in a GRO batch its frames' first
        # datagrams would take the batch's first stamp, up to 0.8 ms early (radar_driver_loop).
        rx = UdpReceiver(link.host, port, accept_from=link.source, receive_stamps=link.receive_stamps,
                         gro=not getattr(stream, "times_by_receipt", False))
    except OSError as exc:  # the port taken, the address not this machine's: say so in one line, and exit
        log.error("radar %s: %s", link.name, exc.strerror or exc)
        raise SystemExit(1) from None
    except SarbotError as exc:  # hardware stamps demanded where the card cannot give them
        log.error("radar %s: %s", link.name, exc)
        raise SystemExit(1) from None
    # Bound first: what the radar sends from now on waits in the socket until the recorder listens.
    pub = publisher_heard_by_recorder(endpoint, f"radar {link.name}", stop, high_water_mark=FRAME_QUEUE)
    if bound_port is not None:
        bound_port.value = rx.address[1]
    log.info("radar %s: %s on %s:%d, %s, UDP GRO %s", link.name, link.wire_format, link.host, rx.address[1],
             rx.stamps.line(), "on (datagrams received in batches)" if rx.gro else "off (one datagram per receive)")
    try:
        radar_driver_loop(rx, link.name, stream, pub, stop)
    finally:
        rx.close()
        pub.close()


def imu_process(port: str, endpoint: str, radar_endpoints: list[str], stop, clock_reference=None,
                frame_duration_ns: dict[str, int] | None = None, radar: str | None = None) -> None:
    """An IMU's driver process: the robot's, or with ``radar`` the one on that radar's mount."""
    become_child(imu_role(radar), realtime=True)
    # The port is opened and read from the start, not once the recorder listens: opening it flushes what
    # waited in it (a SyncIn sent before was lost), so what the loop publishes waits here instead.
    pub = PublisherHoldingForRecorder(endpoint, imu_role(radar))
    log.info("IMU%s on %s", "" if radar is None else f" of radar {radar}", port)
    try:
        imu_driver_loop(port, pub, stop, radar_endpoints=radar_endpoints, clock_reference=clock_reference,
                        frame_duration_ns=frame_duration_ns, radar=radar)
    finally:
        pub.close()


def can_process(config: CanConfig, endpoint: str, stop) -> None:
    become_child("can", realtime=True)
    driver = CanDriver(config.open(), trigger_id=config.trigger_id)  # open first: its queue keeps frames meanwhile
    pub = publisher_heard_by_recorder(endpoint, "can", stop)
    log.info("CAN on %s %s", config.interface, config.channel or "")
    try:
        can_driver_loop(driver, pub, stop)
    finally:
        driver.close()
        pub.close()
