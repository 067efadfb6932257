"""The recorder: everything on the bus into an HDF5 recording (schema v1), crash-safe.

Subscribes to ``radar/<name>``, ``imu``, ``can``, ``trigger`` and ``event``. Data is flushed at least every
``flush_interval_s`` and fsync'ed, so a recorder killed at any moment leaves a file that opens and holds
everything up to its last flush (the writer is in SWMR mode). Every gap in a topic's sequence numbers is
written to ``/events`` with what was lost; so is every event a driver publishes (packet loss, checksum
errors, resyncs). A full disk ends recording with an error and keeps the file readable.
"""

from __future__ import annotations

import errno
import logging
import os
import threading
import time
from pathlib import Path

import numpy as np

from drivers.imu import NO_COUNTER
from drivers.radar import registry
from drivers.radar.stream import RadarFrame
from imaging.core.rig import Rig
from imaging.io.recording import RecordingWriter

from .bus import RECORDER_LISTENING, BusSubscriber
from .messages import (
    CanBatch,
    Event,
    ImuBatch,
    RadarFrameMessage,
    RadarImuBatch,
    Trigger,
    WorkerState,
    decode,
)
from .ptp import PtpStatus, ReceiveDelay

log = logging.getLogger(f"sarbot.{__name__}")


#: Frames of one radar the recorder may be behind (about 26 s at the reference waveform, 360 MB).
RECORDER_FRAME_QUEUE = 500


class DiskFullError(OSError):
    pass


class Recorder:
    """Store what the bus carries into one recording, or a series of parts.

    Parameters
    ----------
    path : str or Path
        The recording; with splitting, parts are ``<stem>_000.h5``, ``<stem>_001.h5``, ...
    rig : Rig
    endpoints : str or list of str
        Bus endpoints of the drivers.
    flush_interval_s : float
        Longest time data stays unflushed (and not fsync'ed).
    wire_formats : dict, optional
        Radar name -> wire format attribute ("SRF1" by default).
    split_bytes, split_s : optional
        Start a new part when the current one reaches this size (checked at every flush) or age. Each
        part is a complete recording: it repeats the rig attributes and the triggers seen so far, and its
        root attributes ``part`` and ``previous_part`` chain the parts.
    min_free_bytes : int
        Recording stops (DiskFullError) when, at a flush, the free space on the file's disk falls below
        this or below twice what the last flush interval wrote, whichever is more. HDF5 does not report a
        failed write where it happens (it surfaces later, when chunks are evicted, and corrupts the file),
        so the recorder stops while the file is still whole rather than wait for ENOSPC.
    frame_endpoints : list of str
        The radars' endpoints: at most ``RECORDER_FRAME_QUEUE`` frames of each wait to be written. A
        recorder that falls further behind (a machine with too little CPU or a disk too slow) loses frames,
        each loss written to /events, instead of taking the machine's memory until it is killed.
    on_event : callable, optional
        Called with every ``Event`` written to /events (the daemon publishes them for viewers).
    receive_stamps : dict, optional
        Radar name -> which receive stamps its driver takes, "hardware" or "software"
        (``drivers.radar.timestamping``): each radar group's ``receive_stamp`` attribute, and with "hardware"
        the receive delay is measured with the card's stamps (``nic_time_ns``). A radar not named is not said.
    receive_stamp_notes : dict, optional
        Radar name -> how its stamps were chosen (``StampChoice.line``): its ``receive_stamp_note`` attribute.
    """

    def __init__(self, path: str | Path, rig: Rig, endpoints, flush_interval_s: float = 0.5, adc_dtype: str = "int16",
                 context=None, wire_formats: dict[str, str] | None = None, split_bytes: int | None = None,
                 split_s: float | None = None, min_free_bytes: int = 64_000_000, frame_endpoints=(), on_event=None,
                 receive_stamps: dict[str, str] | None = None, receive_stamp_notes: dict[str, str] | None = None):
        self.base_path = Path(path)
        self.rig = rig
        self.adc_dtype = adc_dtype
        self.wire_formats = {r.name: (wire_formats or {}).get(r.name, registry.DEFAULT) for r in rig.radars}
        self.receive_stamps = {n: s for n, s in (receive_stamps or {}).items() if n in self.wire_formats}
        self._radar_attrs = {n: {"receive_stamp": s} for n, s in self.receive_stamps.items()}
        for n, note in (receive_stamp_notes or {}).items():
            if n in self._radar_attrs:
                self._radar_attrs[n]["receive_stamp_note"] = note
        self.split_bytes = split_bytes
        self.split_s = split_s
        self.min_free_bytes = min_free_bytes
        self._size_at_flush = 0
        self._fsync: threading.Thread | None = None
        self.paths: list[Path] = []
        self._triggers: list[tuple[int, str]] = []
        self.on_event = on_event
        # Each radar's frames since the last flush, written there in one append per column: seven HDF5 appends
        # (resize and write) a frame were most of the recorder's CPU per frame. What a flush writes is what a
        # killed recorder leaves, as before: data was only ever safe from the flush on.
        self._pending_frames: dict[str, list[RadarFrame]] = {}
        # The IMU's batches (20 a second) likewise: five appends a batch were a sixth of the supervisor's CPU.
        self._pending_imu: list[ImuBatch] = []
        self.writer = self._open_part()
        self._handlers = {RadarFrameMessage: self._store_frame, ImuBatch: self._store_imu, CanBatch: self._store_can,
                          Trigger: self._store_trigger, Event: self._store_event, WorkerState: self._note_worker,
                          RadarImuBatch: self._store_radar_imu}
        if rig.radars:  # the frames' checksum kernel loaded (in a fresh checkout compiled) before a driver is let
            from imaging.io.fletcher32 import fletcher32  # go, not at the first flush, holding up the bus as long

            fletcher32(b"\0\0")
        # RECORDER_LISTENING last: a driver that sees it knows the subscriptions before it have arrived too.
        # The drivers wait for it, so their sensor data is counted from its first message (none goes unseen).
        self.sub = BusSubscriber(endpoints, topics=[*(cls.TOPIC for cls in self._handlers), RECORDER_LISTENING],
                                 context=context, high_water_marks=dict.fromkeys(frame_endpoints, RECORDER_FRAME_QUEUE),
                                 counted_from_start=(RadarFrameMessage.TOPIC, ImuBatch.TOPIC, RadarImuBatch.TOPIC,
                                                     CanBatch.TOPIC, Trigger.TOPIC))
        self.flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self._reported_missed: dict[str, int] = {}
        self.frames = {r.name: 0 for r in rig.radars}
        self.imu_samples = 0
        self.radar_imu_samples: dict[str, int] = {}  # by radar: samples of the IMUs on radar mounts
        self.radar_imu_unrecorded: dict[str, int] = {}  # by radar: samples of an IMU the rig does not declare
        self.radar_imu_drift_ppm: dict[str, float] = {}
        self.can_frames = 0
        # For health reports: what went wrong, and the clocks' state.
        self.invalid_frames = {r.name: 0 for r in rig.radars}
        self.wire_events = 0
        self.ptp_locked: dict[str, bool] = {}
        self.unlocked_frames = {r.name: 0 for r in rig.radars}  # recorded and marked in /radar/NAME/ptp_locked
        self.receive_delay = {r.name: ReceiveDelay() for r in rig.radars}  # host receive minus frame end
        # With hardware stamps: frames whose last datagram the card left unstamped (kept out of receive_delay,
        # whose series stays on one clock).
        self.nic_unstamped = {n: 0 for n, s in self.receive_stamps.items() if s == "hardware"}
        self._frame_duration_ns = {r.name: r.waveform.frame_duration_ns for r in rig.radars}
        self.ptp_status: PtpStatus | None = None  # the host's, as the daemon last read it
        self.triggers_seen = 0
        self.imu_drift_ppm: float | None = None
        self.latencies_ns: list[int] = []  # datagram (kernel time stamp) to recorder, per radar frame
        self.worker_states: dict[str, WorkerState] = {}
        self.conditions: dict[str, str] = {}  # lasting trouble a driver said (Event.condition), by source
        # By IMU topic: the publisher of the last batch, its last sample (counter, time) and sample period.
        self._imu_last: dict[str, tuple[str, int, int, int | None]] = {}
        self._publisher = ""  # of the message being stored
        self.imu_samples_lost = 0  # across driver restarts (each also written to /events)

    @property
    def path(self) -> Path:
        """The part being written."""
        return self.paths[-1]

    def _open_part(self) -> RecordingWriter:
        split = self.split_bytes is not None or self.split_s is not None
        part = len(self.paths)
        path = self.base_path.with_name(f"{self.base_path.stem}_{part:03d}{self.base_path.suffix}") if split else self.base_path
        chain = {"part": part, "previous_part": self.paths[-1].name if self.paths else ""} if split else None
        writer = RecordingWriter(path, self.rig.radars, imu=self.rig.imu, adc_dtype=self.adc_dtype,
                                 wire_format=self.wire_formats, root_attrs=chain, clock_state=True,
                                 radar_attrs=self._radar_attrs, events_time_base="host")
        for t, source in self._triggers:  # each part says how its times were tied to the first chirp
            writer.append_trigger(t, source)
        self.paths.append(path)
        self._opened = time.monotonic()
        return writer

    def _split_due(self) -> bool:
        if self.split_s is not None and time.monotonic() - self._opened >= self.split_s:
            return True
        return self.split_bytes is not None and self.path.stat().st_size >= self.split_bytes

    def step(self, timeout_ms: int = 100) -> bool:
        """Receive and store one message (or time out); flush when due. Returns False on timeout."""
        msg = self.sub.receive(timeout_ms=timeout_ms)
        if msg is not None:
            self._store(msg)
            self._report_gaps(msg.topic, msg.host_time_ns)  # /events is on the host clock
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self.flush()
            if self._split_due():
                self._next_part()
        return msg is not None

    def _next_part(self) -> None:
        old = self.path
        self.writer.close()
        self.writer = self._open_part()
        log.info("recording continues in %s (after %s)", self.path, old.name)

    def _store(self, msg) -> None:
        message = decode(msg)
        self._publisher = msg.header.get("pub", "")
        try:
            self._handlers[type(message)](message)
        except OSError as exc:
            self._raise_if_disk_full(exc)
            raise

    def _store_frame(self, m: RadarFrameMessage) -> None:
        f = m.frame
        if f.iq.shape != self.writer.adc_shape(m.radar):  # said now, not at the flush that would write it
            raise ValueError(f"radar {m.radar}: adc shape {f.iq.shape} does not fit {self.writer.adc_shape(m.radar)}")
        self._pending_frames.setdefault(m.radar, []).append(f)
        self.frames[m.radar] += 1
        # A frame of which no datagram came (lost whole: a placeholder) has no receive time of its own; the
        # one it carries is interpolated between its neighbours', for the file's order, not a measurement.
        lost_whole = f.bytes_missing >= f.iq.nbytes
        if f.receive_ns > 0 and not lost_whole:
            self.latencies_ns.append(time.time_ns() - f.receive_ns)
        self.invalid_frames[m.radar] += 0 if f.valid else 1
        # A frame from an unlocked clock is kept, and marked (``_write_frames``): never mixed in silently.
        self.unlocked_frames[m.radar] += 0 if f.ptp_locked else 1
        was = self.ptp_locked.get(m.radar)
        if was is not None and was != f.ptp_locked:
            self._write_event(f.receive_ns, f"radar.{m.radar}", "info" if f.ptp_locked else "warning",
                              "clock PTP-locked again" if f.ptp_locked else
                              f"clock not PTP-locked: frames from {f.frame_counter} marked in /radar/{m.radar}/ptp_locked")
        self.ptp_locked[m.radar] = f.ptp_locked
        if lost_whole:
            return
        receive_ns = f.receive_ns
        if m.radar in self.nic_unstamped:  # hardware stamps: the delay on the card's clock, never mixed with the host's
            receive_ns = f.nic_receive_ns
            if not receive_ns and f.receive_ns > 0:
                if not self.nic_unstamped[m.radar]:
                    self._write_event(f.receive_ns, f"radar.{m.radar}", "warning",
                                      f"frame {f.frame_counter}: its last datagram has no hardware receive stamp; such "
                                      "frames keep the host's stamp only (0 in nic_time_ns) and are left out of the receive delay")
                self.nic_unstamped[m.radar] += 1
        jump = self.receive_delay[m.radar].add(receive_ns, f.frame_time_ns + self._frame_duration_ns[m.radar])
        if jump:
            self._write_event(f.receive_ns, f"radar.{m.radar}", "warning", jump)

    def _check_imu_continuity(self, topic: str, b: ImuBatch) -> None:
        """Samples lost where one IMU driver process ended and the next began (killed, restarted).

        Within a driver's run its Xbus parser counts packet-counter gaps (its events); across a restart
        nobody did: the first batch of a new publisher is compared with the last sample recorded, by the
        IMU's packet counter (16 bits) and, where that is missing or wrapped, by the sample times."""
        if not len(b):
            return
        last = self._imu_last.get(topic)
        t = np.asarray(b.time_ns, np.int64)
        counter = np.asarray(b.counter, np.int64)
        period = int(np.median(np.diff(t))) if t.size > 1 else (last[3] if last else None)
        self._imu_last[topic] = (self._publisher, int(counter[-1]), int(t[-1]), period)
        if last is None or last[0] == self._publisher:
            return
        _, last_counter, last_t, last_period = last
        period = period or last_period
        gap_ns = int(t[0]) - last_t
        by_time = round(gap_ns / period) - 1 if period else None
        if last_counter != NO_COUNTER and counter[0] != NO_COUNTER:
            lost = (int(counter[0]) - last_counter - 1) & 0xFFFF
            if by_time is not None and by_time > lost + 0xFFFF // 2:  # the 16-bit counter wrapped on the way
                lost = by_time
        elif by_time is not None:
            lost = by_time
        else:
            return
        if lost <= 0:
            return
        self.imu_samples_lost += lost
        text = (f"{topic}: {lost} sample(s) lost ({(gap_ns - (period or 0)) / 1e9:.3f} s) across a restart of its "
                f"driver (counter {last_counter} to {int(counter[0])})")
        log.warning("%s", text)
        self._write_event(int(b.host_time_ns[0]), "recorder", "error", text)  # /events is on the host clock

    def _store_imu(self, m: ImuBatch) -> None:
        self._check_imu_continuity(m.TOPIC, m)
        if len(m):
            self._pending_imu.append(m)  # written at the flush, as the frames are
        self.imu_samples += len(m)
        if m.clock_drift_ppm is not None:
            self.imu_drift_ppm = float(m.clock_drift_ppm)

    def _store_radar_imu(self, m: RadarImuBatch) -> None:
        if not self.writer.has_radar_imu(m.radar):
            # Only a rig's [radar.NAME.imu] says how that IMU sits (its rate, noise): without it the samples
            # could not be read back as the radar's. Said once in /events, counted after.
            if m.radar not in self.radar_imu_unrecorded:
                text = (f"samples of an IMU on radar {m.radar!r}, which the rig does not declare ([radar.{m.radar}.imu]): "
                        "not recorded")
                log.error(text)
                self._write_event(time.time_ns(), "recorder", "error", text)
            self.radar_imu_unrecorded[m.radar] = self.radar_imu_unrecorded.get(m.radar, 0) + len(m)
            return
        b = m.batch
        self._check_imu_continuity(RadarImuBatch.topic_of(m.radar), b)
        self.writer.append_radar_imu(m.radar, b.time_ns, b.gyro_radps, b.accel_mps2, b.counter, b.host_time_ns)
        self.radar_imu_samples[m.radar] = self.radar_imu_samples.get(m.radar, 0) + len(m)
        if b.clock_drift_ppm is not None:
            self.radar_imu_drift_ppm[m.radar] = float(b.clock_drift_ppm)

    def _store_can(self, m: CanBatch) -> None:
        self.writer.append_can(m.time_ns, m.arbitration_id, m.dlc, m.data)
        self.can_frames += len(m)

    def _store_trigger(self, m: Trigger) -> None:
        self.writer.append_trigger(m.time_ns, m.source)
        self._triggers.append((m.time_ns, m.source))
        self.triggers_seen += 1

    def _note_worker(self, m: WorkerState) -> None:
        """Not stored: the workers' state goes into health (and their events into /events)."""
        self.worker_states[m.role] = m

    def _store_event(self, m: Event) -> None:
        self.wire_events += 1
        self._write_event(m.time_ns, m.source, m.level, m.message)
        if m.condition:
            self.conditions[m.source] = m.message

    def _write_event(self, time_ns: int, source: str, level: str, message: str) -> None:
        """Into /events, and to ``on_event`` (the daemon publishes every event for viewers)."""
        self.writer.append_event(time_ns, source, level, message)
        if self.on_event is not None:
            self.on_event(Event(time_ns, source, level, message))

    def _raise_if_disk_full(self, exc: OSError) -> None:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG) or "No space" in str(exc) or "disk quota" in str(exc).lower():
            raise DiskFullError(errno.ENOSPC, f"{self.path}: disk full; recording stopped") from None

    @property
    def bus_lost(self) -> int:
        """Messages lost on the way to the recorder so far (each also written to /events)."""
        return self.sub.missed

    def record_ptp(self, status: PtpStatus, events=(), time_ns: int | None = None) -> None:
        """The host's PTP state (``acquisition.ptp.PtpMonitor.poll``) into /ptp, its events into /events."""
        time_ns = time.time_ns() if time_ns is None else int(time_ns)
        self.ptp_status = status
        self.writer.append_ptp(time_ns, status.port_state, status.offset_from_master_ns, status.mean_path_delay_ns,
                               status.phc2sys_offset_ns)
        for e in events:
            self._write_event(time_ns, "ptp", e.level, e.message)

    def record_event(self, time_ns: int, source: str, level: str, message: str) -> None:
        """An event of the supervisor's own (a restart) into /events."""
        self._write_event(time_ns, source, level, message)

    def _report_gaps(self, topic: str, time_ns: int) -> None:
        st = self.sub.stats[topic]
        before = self._reported_missed.get(topic, 0)
        if st.missed > before:
            self._write_event(time_ns, "bus", "error", f"{topic}: {st.missed - before} message(s) lost on the bus")
            self._reported_missed[topic] = st.missed

    def _write_frames(self) -> None:
        """Append the frames and IMU batches stored since the last flush, each radar's frames and the IMU's
        samples in one append per column."""
        for radar, frames in self._pending_frames.items():
            if frames:
                # The frames as received (views on the bus messages), not stacked: each is one chunk of the file.
                self.writer.append_frames(radar, [f.iq for f in frames], [f.frame_time_ns for f in frames],
                                          [f.frame_counter for f in frames], [f.receive_ns for f in frames],
                                          [1 if f.valid else 0 for f in frames])
                self.writer.append_frame_clock(radar, [f.ptp_locked for f in frames],
                                               [f.nic_receive_ns for f in frames])
        self._pending_frames = {}
        if self._pending_imu:
            b = self._pending_imu
            self.writer.append_imu(np.concatenate([m.time_ns for m in b]), np.concatenate([m.gyro_radps for m in b]),
                                   np.concatenate([m.accel_mps2 for m in b]), np.concatenate([m.counter for m in b]),
                                   np.concatenate([m.host_time_ns for m in b]))
            self._pending_imu = []

    def flush(self) -> None:
        try:
            self._write_frames()
            if self.imu_drift_ppm is not None:
                self.writer.set_imu_clock_drift_ppm(self.imu_drift_ppm)
            for radar, drift in self.radar_imu_drift_ppm.items():
                self.writer.set_imu_clock_drift_ppm(drift, radar)
            self.writer.flush()
            self._fsync_in_background(self.writer.fileno())
        except OSError as exc:
            self._raise_if_disk_full(exc)
            raise
        self._last_flush = time.monotonic()
        self._check_free_space()

    def _fsync_in_background(self, fd: int) -> None:
        """After the flush the data is in the page cache (a killed process loses none of it); fsync takes it
        to the disk (power loss). At 55 MB/s that takes long enough to stall reception, so it runs beside
        the loop, one at a time."""
        if self._fsync is not None and self._fsync.is_alive():
            return  # the next flush syncs what this one would have
        self._fsync = threading.Thread(target=_fsync_quietly, args=(fd,), daemon=True)
        self._fsync.start()

    def _check_free_space(self) -> None:
        size = self.path.stat().st_size
        grown, self._size_at_flush = size - self._size_at_flush, size
        st = os.statvfs(self.path.parent)
        free = st.f_bavail * st.f_frsize
        reserve = max(self.min_free_bytes, 2 * grown)
        if free < reserve:
            raise DiskFullError(errno.ENOSPC, f"{self.path}: disk full ({free / 1e6:.1f} MB free, {reserve / 1e6:.1f} MB "
                                              "needed to go on); recording stopped")

    def close(self) -> None:
        try:
            self.flush()
            if self._fsync is not None:
                self._fsync.join()
            os.fsync(self.writer.fileno())
        except DiskFullError:
            pass  # already flushed: what is there is whole
        finally:
            try:
                self.writer.close()
            except (OSError, RuntimeError) as exc:  # a full disk: what the last flush wrote stays readable
                log.error("closing %s: %s", self.path, exc)
            self.sub.close()


def _fsync_quietly(fd: int) -> None:
    try:
        os.fsync(fd)
    except OSError as exc:  # the file was closed meanwhile, or the disk failed: the next flush reports it
        log.debug("fsync: %s", exc)

