"""The host's PTP state from linuxptp, and each radar's receive delay: what health, /events and the recording
say about the clocks.

``ptp4l`` answers management requests on its UNIX socket (``uds_address``, /var/run/ptp4l by default);
``pmc -u`` is linuxptp's own client for it, so its text output is what is parsed here (PORT_DATA_SET: the
port state; CURRENT_DATA_SET: offset from master, mean path delay, steps removed; TIME_STATUS_NP: the
grandmaster and whether one is present). ``phc2sys`` serves no management requests: its offset comes from
its log lines (``CLOCK_REALTIME phc offset -12 s2 freq +3 delay 500``), e.g. the journal of its unit, and so do
its refusals: phc2sys copies a PTP hardware clock (PHC) to another clock and has nothing to do without one
-- with ptp4l on software time stamps (``-S``) ptp4l steers CLOCK_REALTIME itself, and phc2sys says "no
suitable ports available" (``-a``) or "interface X does not have a PHC" (``-s X``). Such a line is the
status's ``phc2sys_error`` and an event, never an offset. See docs/architecture.md#receive-time-stamps.

``PtpMonitor.poll`` returns the state and the events a change calls for: the port state changing, the offset
stepping (a jump larger than ``step_ns`` between two polls), ptp4l no longer answering. ``ReceiveDelay``
follows a radar's host receive time minus frame end (the network path plus the radar's clock error: a
radar whose clock loses its lock drifts or steps against the host) and says when it jumps.
See docs/bus.md (health) and docs/formats/recording.md (/ptp, /events).
"""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess

import numpy as np

DEFAULT_PTP4L_SOCKET = "/var/run/ptp4l"

#: Port states in which the host's clock follows a master (linuxptp's names).
FOLLOWING_STATES = ("SLAVE", "UNCALIBRATED")


@dataclasses.dataclass
class PtpStatus:
    """The host's PTP state as ptp4l (and phc2sys, where its log is read) report it; ns unless named."""

    port_state: str  # ptp4l's port state (LISTENING, UNCALIBRATED, SLAVE, MASTER, FAULTY, ...) or UNREACHABLE
    offset_from_master_ns: float | None = None
    mean_path_delay_ns: float | None = None
    steps_removed: int | None = None
    grandmaster: str | None = None
    grandmaster_present: bool | None = None
    phc2sys_offset_ns: float | None = None
    phc2sys_state: str | None = None  # the servo state of its latest line: s0 unlocked, s1 step, s2 locked
    phc2sys_error: str | None = None  # what phc2sys last said instead of an offset (it has no PHC, no rights)
    error: str | None = None  # why ptp4l could not be asked

    @property
    def reachable(self) -> bool:
        return self.error is None

    def line(self) -> str:
        """One phrase for the health line."""
        if self.error:
            return f"PTP host: {self.error}"
        parts = [f"PTP host {self.port_state}"]
        if self.offset_from_master_ns is not None and self.port_state in FOLLOWING_STATES:
            parts.append(f"offset {self.offset_from_master_ns:.0f} ns")
        if self.mean_path_delay_ns is not None and self.port_state in FOLLOWING_STATES:
            parts.append(f"path delay {self.mean_path_delay_ns:.0f} ns")
        if self.phc2sys_offset_ns is not None:
            parts.append(f"phc2sys offset {self.phc2sys_offset_ns:.0f} ns")
        if self.phc2sys_error is not None:
            parts.append(f"phc2sys: {self.phc2sys_error}")
        return " ".join(parts)


_VALUE = re.compile(r"^\s+(\w+)\s+(\S+)\s*$")


def parse_pmc(text: str) -> dict[str, str]:
    """The ``name value`` lines of pmc's answers, merged into one table (the data sets asked here share no
    field names)."""
    fields = {}
    for line in text.splitlines():
        m = _VALUE.match(line)
        if m and "RESPONSE" not in line:
            fields[m.group(1)] = m.group(2)
    return fields


def status_from_pmc(fields: dict[str, str]) -> PtpStatus:
    """A PtpStatus from ``parse_pmc``'s table; FileFormatError-free: missing fields stay None."""

    def number(key):
        try:
            return float(fields[key])
        except (KeyError, ValueError):
            return None

    steps = number("stepsRemoved")
    present = fields.get("gmPresent")
    return PtpStatus(port_state=fields.get("portState", "UNKNOWN"), offset_from_master_ns=number("offsetFromMaster"),
                     mean_path_delay_ns=number("meanPathDelay"), steps_removed=None if steps is None else int(steps),
                     grandmaster=fields.get("gmIdentity"),
                     grandmaster_present=None if present is None else present == "true")


def query_ptp4l(socket_path: str = DEFAULT_PTP4L_SOCKET, timeout_s: float = 2.0, pmc: str | None = None) -> PtpStatus:
    """Ask ptp4l through its management socket (``pmc -u``). Never raises: an unreachable ptp4l is a status
    (port_state UNREACHABLE and the reason), since the daemon keeps recording without it."""
    pmc = pmc or shutil.which("pmc") or "/usr/sbin/pmc"
    cmd = [pmc, "-u", "-b", "0", "-s", socket_path,
           "GET PORT_DATA_SET", "GET CURRENT_DATA_SET", "GET TIME_STATUS_NP"]
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except FileNotFoundError:
        return PtpStatus("UNREACHABLE", error="pmc not found (install linuxptp)")
    except subprocess.TimeoutExpired:
        return PtpStatus("UNREACHABLE", error=f"ptp4l at {socket_path} did not answer within {timeout_s:.0f} s")
    fields = parse_pmc(res.stdout)
    if "portState" not in fields:
        return PtpStatus("UNREACHABLE", error=f"ptp4l at {socket_path} did not answer")
    return status_from_pmc(fields)


_PHC2SYS = re.compile(r"(?P<clock>\S+) (?:phc|sys) offset\s+(?P<offset>-?\d+) s(?P<state>\d)\s+freq\s+(?P<freq>[-+]?\d+)"
                      r"(?:\s+delay\s+(?P<delay>\d+))?")


def parse_phc2sys_line(line: str) -> tuple[float, str] | None:
    """(offset ns, servo state s0/s1/s2) of one phc2sys log line; None for other lines."""
    m = _PHC2SYS.search(line)
    if m is None:
        return None
    return float(m.group("offset")), f"s{m.group('state')}"


#: What phc2sys logs when it cannot do its work (linuxptp 3.1: phc2sys.c, clockadj.c): the line's text from
#: here on is the error.
_PHC2SYS_ERRORS = re.compile(r"(no suitable ports available|interface \S+ does not have a PHC|"
                             r"failed to (?:adjust|step|set) the clock(?: status)?: .*|Waiting for ptp4l)")


def parse_phc2sys_error(line: str) -> str | None:
    """What a phc2sys log line says it cannot do (no PHC to copy, no right to adjust a clock, ptp4l not yet
    following a master); None for other lines."""
    m = _PHC2SYS_ERRORS.search(line)
    return None if m is None else m.group(1).strip()


@dataclasses.dataclass
class PtpEvent:
    """Something /events should hold: a level (info, warning) and the message."""

    level: str
    message: str


class PtpMonitor:
    """Polls ptp4l (and takes phc2sys log lines) and says what changed.

    ``step_ns``: an offset that moves by more than this between two polls is a step (a clock stepped, a new
    master); ``query``: how to ask ptp4l (a function returning PtpStatus; tests may pass their own).
    """

    def __init__(self, socket_path: str = DEFAULT_PTP4L_SOCKET, step_ns: float = 100_000.0, query=None):
        self.socket_path = socket_path
        self.step_ns = float(step_ns)
        self._query = query or (lambda: query_ptp4l(self.socket_path))
        self.status: PtpStatus | None = None
        self._phc2sys: tuple[float, str] | None = None
        self._phc2sys_error: str | None = None

    def phc2sys_line(self, line: str) -> None:
        """Take one line of phc2sys's log: an offset, or what it cannot do (an offset after it clears that)."""
        parsed = parse_phc2sys_line(line)
        if parsed is not None:
            self._phc2sys, self._phc2sys_error = parsed, None
        elif (error := parse_phc2sys_error(line)) is not None:
            self._phc2sys_error = error

    def poll(self) -> tuple[PtpStatus, list[PtpEvent]]:
        new = self._query()
        if self._phc2sys is not None:
            new.phc2sys_offset_ns, new.phc2sys_state = self._phc2sys
        new.phc2sys_error = self._phc2sys_error
        events = self.changes(self.status, new)
        self.status = new
        return new, events

    def changes(self, old: PtpStatus | None, new: PtpStatus) -> list[PtpEvent]:
        """The events between two polls."""
        events = []
        if old is None:
            level = "info" if new.reachable else "warning"
            return [PtpEvent(level, new.line() if new.error else f"PTP host: {new.line().removeprefix('PTP host').strip()}")]
        if new.reachable != old.reachable:
            if not new.reachable:
                return [PtpEvent("warning", f"PTP host: {new.error}")]
            events.append(PtpEvent("info", f"PTP host: ptp4l answers again ({new.port_state})"))
        if new.reachable and old.reachable and new.port_state != old.port_state:
            level = "info" if new.port_state in FOLLOWING_STATES + ("MASTER",) else "warning"
            events.append(PtpEvent(level, f"PTP host: port {old.port_state} -> {new.port_state}"))
        if new.grandmaster and old.grandmaster and new.grandmaster != old.grandmaster:
            events.append(PtpEvent("warning", f"PTP host: grandmaster {old.grandmaster} -> {new.grandmaster}"))
        if (new.port_state in FOLLOWING_STATES and old.port_state in FOLLOWING_STATES
                and new.offset_from_master_ns is not None and old.offset_from_master_ns is not None
                and abs(new.offset_from_master_ns - old.offset_from_master_ns) > self.step_ns):
            events.append(PtpEvent("warning", f"PTP host: offset stepped {old.offset_from_master_ns:.0f} -> "
                                              f"{new.offset_from_master_ns:.0f} ns"))
        if new.phc2sys_error is not None and new.phc2sys_error != old.phc2sys_error:
            events.append(PtpEvent("warning", f"PTP host: phc2sys: {new.phc2sys_error}"))
        if (new.phc2sys_offset_ns is not None and old.phc2sys_offset_ns is not None
                and abs(new.phc2sys_offset_ns - old.phc2sys_offset_ns) > self.step_ns):
            events.append(PtpEvent("warning", f"PTP host: phc2sys offset stepped {old.phc2sys_offset_ns:.0f} -> "
                                              f"{new.phc2sys_offset_ns:.0f} ns"))
        return events


@dataclasses.dataclass
class ReceiveDelayStats:
    """A radar's host receive time minus frame end over the recent frames, ms."""

    median_ms: float
    p99_ms: float
    frames: int


class ReceiveDelay:
    """A radar's host receive time minus the end of its frame (its own clock): the distribution over the last
    ``window`` frames, and a jump -- ``confirm`` frames in a row off the line the recent delays follow, by
    more than ``jump_ms`` and more than ``scatter_factor`` times the delays' own scatter about that line, and
    within that of each other -- reported once, after which the new level is the reference.

    A line, not a level: where the two clocks run at different rates (a replay at 0.5x, an unlocked radar
    clock drifting) the delay grows steadily, which is a rate and no jump. Against the scatter: a host whose
    sockets are read late by varying amounts (an emulator on a loaded machine: +-15 ms) has latency (health
    shows it), not a step of a clock. A new level held: a few frames late by different amounts are no step.

    The receive time is the host's kernel stamp, or with hardware receive stamps the network card's (its PTP
    hardware clock): one clock per radar, never both (the recorder leaves out a frame the card did not stamp).
    What the level means depends on that clock: docs/architecture.md (receive time stamps).
    """

    def __init__(self, window: int = 200, jump_ms: float = 5.0, confirm: int = 8, scatter_factor: float = 6.0):
        self.window = window
        self.jump_ms = jump_ms
        self.confirm = confirm
        self.scatter_factor = scatter_factor
        # The recent frames (frame end s, delay ms), oldest first, in [_start, _end) of arrays twice the window
        # long: taken every frame as views, never rebuilt from a deque of tuples (that and np.polyfit were a
        # tenth of the recorder's CPU per frame in a four-radar run).
        self._t_s = np.empty(2 * window)
        self._d_ms = np.empty(2 * window)
        self._start = self._end = 0
        self._outliers: list[tuple[float, float, float]] = []  # (frame end s, ms, off the line ms)

    def __len__(self) -> int:
        return self._end - self._start

    def _append(self, t_s: float, d_ms: float) -> None:
        if self._end == self._t_s.size:  # full to the end: the newest window - 1 move to the front
            keep = self.window - 1
            self._t_s[:keep] = self._t_s[self._end - keep:self._end]
            self._d_ms[:keep] = self._d_ms[self._end - keep:self._end]
            self._start, self._end = 0, keep
        self._t_s[self._end] = t_s
        self._d_ms[self._end] = d_ms
        self._end += 1
        self._start = max(self._start, self._end - self.window)

    def _line(self, t_s: float) -> tuple[float, float]:
        """The delay the recent frames' line expects at ``t_s``, ms, and their scatter about it (robust sigma).

        The least-squares line in closed form about the frames' mean time (as ``np.polyfit(t, d, 1)`` fits
        it, to about 1e-12 ms: tests/test_ptp.py)."""
        t, d = self._t_s[self._start:self._end], self._d_ms[self._start:self._end]
        if t[-1] - t[0] <= 0 and np.ptp(t) <= 0:
            return float(np.median(d)), float(1.4826 * np.median(np.abs(d - np.median(d))))
        x = t - t[0]
        x_mean, d_mean = x.mean(), d.mean()
        dx = x - x_mean
        slope = float(dx @ (d - d_mean)) / float(dx @ dx)
        intercept = d_mean - slope * x_mean
        residual = d - (intercept + slope * x)
        return float(intercept + slope * (t_s - t[0])), float(1.4826 * np.median(np.abs(residual)))

    def add(self, receive_ns: int, frame_end_ns: int) -> str | None:
        """Take one frame; returns the jump's message when this frame confirms one."""
        if receive_ns <= 0:
            return None  # a frame of which no datagram came has no receive time
        d = (receive_ns - frame_end_ns) * 1e-6
        t = frame_end_ns * 1e-9
        if len(self) >= 10:
            expected, scatter = self._line(t)
            threshold = max(self.jump_ms, self.scatter_factor * scatter)
            off = d - expected
            if abs(off) > threshold:
                if self._outliers and abs(off - float(np.median([o[2] for o in self._outliers]))) > threshold:
                    self._outliers = []  # off the line, but not at the level the ones before it were: jitter
                self._outliers.append((t, d, off))
                if len(self._outliers) < self.confirm:
                    return None
                new = float(np.median([o[1] for o in self._outliers]))
                self._start = self._end = 0
                for o in self._outliers:
                    self._append(o[0], o[1])
                self._outliers = []
                return f"receive time minus frame end jumped from {expected:.1f} ms to {new:.1f} ms"
        self._outliers = []
        self._append(t, d)
        return None

    def stats(self) -> ReceiveDelayStats | None:
        if not len(self):
            return None
        d = self._d_ms[self._start:self._end]
        return ReceiveDelayStats(float(np.median(d)), float(np.percentile(d, 99)), int(d.size))


class LogFollower:
    """The lines appended to a log file since the last call (phc2sys's ``-m`` output redirected to a file):
    from its end when first opened, again from the start when it was rotated or truncated."""

    def __init__(self, path: str):
        self.path = path
        self._offset: int | None = None

    def new_lines(self) -> list[str]:
        import os

        try:
            size = os.path.getsize(self.path)
        except OSError:
            return []
        if self._offset is None or size < self._offset:
            self._offset = size if self._offset is None else 0
        if size == self._offset:
            return []
        with open(self.path, "rb") as fh:
            fh.seek(self._offset)
            data = fh.read(size - self._offset)
        end = data.rfind(b"\n") + 1  # a line still being written waits for the next call
        self._offset += end
        return data[:end].decode(errors="replace").splitlines()


class PtpPoller:
    """Polls a ``PtpMonitor`` every ``interval_s`` on a thread of its own (pmc takes milliseconds the
    recorder's loop must not wait for), first feeding it the lines phc2sys has logged since (``phc2sys_log``,
    a file); ``drain`` hands over (time_ns, status, events) in order."""

    def __init__(self, monitor: PtpMonitor, interval_s: float = 1.0, phc2sys_log: str | None = None):
        import queue
        import threading

        self.monitor = monitor
        self.interval_s = interval_s
        self._phc2sys = LogFollower(phc2sys_log) if phc2sys_log else None
        self._queue: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ptp-poller", daemon=True)

    def start(self) -> "PtpPoller":
        self._thread.start()
        return self

    def _run(self) -> None:
        import time

        while not self._stop.is_set():
            for line in self._phc2sys.new_lines() if self._phc2sys else ():
                self.monitor.phc2sys_line(line)
            status, events = self.monitor.poll()
            self._queue.put((time.time_ns(), status, events))
            self._stop.wait(self.interval_s)

    def drain(self) -> list[tuple[int, PtpStatus, list[PtpEvent]]]:
        out = []
        while not self._queue.empty():
            out.append(self._queue.get_nowait())
        return out

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
