"""The recorder: everything on the bus into an HDF5 recording (schema v1), crash-safe.

Subscribes to ``radar/<name>``, ``imu``, ``trigger`` and ``event``. Data is flushed at least every
``flush_interval_s`` and fsync'ed, so a recorder killed at any moment leaves a file that opens and holds
everything up to its last flush (the writer is in SWMR mode). Every gap in a topic's sequence numbers is
written to ``/events`` with what was lost; so is every event a driver publishes (packet loss, checksum
errors, resyncs). A full disk ends recording with an error and keeps the file readable.
"""

from __future__ import annotations

import errno
import logging
import os
import time
from pathlib import Path

import numpy as np

from imaging.recording import RecordingWriter
from imaging.rig import Rig

from .bus import BusSubscriber

log = logging.getLogger(__name__)


class DiskFullError(OSError):
    pass


class Recorder:
    def __init__(self, path: str | Path, rig: Rig, endpoints, flush_interval_s: float = 0.5, adc_dtype: str = "int16",
                 context=None):
        self.path = Path(path)
        self.rig = rig
        self.writer = RecordingWriter(self.path, rig.radars, imu=rig.imu, adc_dtype=adc_dtype, wire_format="SRF1")
        self.sub = BusSubscriber(endpoints, topics=["radar/", "imu", "trigger", "event"], context=context)
        self.flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self._reported_missed: dict[str, int] = {}
        self.frames = {r.name: 0 for r in rig.radars}
        self.imu_samples = 0

    def step(self, timeout_ms: int = 100) -> bool:
        """Receive and store one message (or time out); flush when due. Returns False on timeout."""
        msg = self.sub.receive(timeout_ms=timeout_ms)
        if msg is not None:
            self._store(msg)
            self._report_gaps(msg.topic, msg.sensor_time_ns)
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self.flush()
        return msg is not None

    def _store(self, msg) -> None:
        w = self.writer
        try:
            if msg.topic.startswith("radar/"):
                name = msg.topic.split("/", 1)[1]
                iq = msg.arrays[0]
                w.append_frames(name, iq[None], [msg.header["frame_time_ns"]], [msg.header["frame_counter"]],
                                [msg.header["receive_ns"]], [1 if msg.header["valid"] else 0])
                self.frames[name] += 1
            elif msg.topic == "imu":
                t, gyro, accel, counter, host = msg.arrays
                w.append_imu(t, gyro, accel, counter, host)
                self.imu_samples += len(t)
            elif msg.topic == "trigger":
                w.append_trigger(msg.sensor_time_ns, msg.header.get("source", "trigger"))
            elif msg.topic == "event":
                w.append_event(msg.sensor_time_ns, msg.header.get("source", "?"), msg.header.get("level", "info"),
                               msg.header.get("message", ""))
        except OSError as exc:
            if exc.errno == errno.ENOSPC or "No space" in str(exc):
                raise DiskFullError(errno.ENOSPC, f"{self.path}: disk full; recording stopped") from None
            raise

    def _report_gaps(self, topic: str, time_ns: int) -> None:
        st = self.sub.stats[topic]
        before = self._reported_missed.get(topic, 0)
        if st.missed > before:
            self.writer.append_event(time_ns, "bus", "error", f"{topic}: {st.missed - before} message(s) lost on the bus")
            self._reported_missed[topic] = st.missed

    def flush(self) -> None:
        self.writer.flush()
        fd = self.writer._f.id.get_vfd_handle()
        try:
            os.fsync(fd)
        except (OSError, TypeError):
            pass
        self._last_flush = time.monotonic()

    def close(self) -> None:
        try:
            self.flush()
        finally:
            self.writer.close()
            self.sub.close()


def publish_frame(pub, radar: str, frame, shape) -> None:
    """A reassembled SRF1 frame onto the bus (what the radar driver does for each frame)."""
    iq = np.frombuffer(bytes(frame.data), dtype="<i2").reshape(shape)
    pub.publish(f"radar/{radar}", frame.frame_time_ns, [iq], frame_counter=frame.frame_counter,
                frame_time_ns=frame.frame_time_ns, receive_ns=frame.last_receive_ns, valid=frame.valid,
                bytes_missing=frame.bytes_missing)
