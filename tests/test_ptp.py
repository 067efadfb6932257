"""The host's PTP state from linuxptp (ptp4l through pmc, phc2sys's log), each radar's receive delay, and where
they go: health, /events, the recording."""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import subprocess
import time

import msgpack
import numpy as np
import pytest

from acquisition.bus import Message
from acquisition.messages import ClockState, Health
from acquisition.ptp import (
    FOLLOWING_STATES,
    PtpMonitor,
    PtpStatus,
    ReceiveDelay,
    parse_phc2sys_error,
    parse_phc2sys_line,
    parse_pmc,
    query_ptp4l,
    status_from_pmc,
)
from imaging.core.rig import default_rig
from imaging.io.recording import Recording, RecordingWriter

# What pmc printed for a ptp4l slave in software-timestamping mode (linuxptp 3.1.1).
PMC_SLAVE = """sending: GET PORT_DATA_SET
\teab52b.fffe.8491cc-1 seq 0 RESPONSE MANAGEMENT PORT_DATA_SET
\t\tportIdentity            eab52b.fffe.8491cc-1
\t\tportState               UNCALIBRATED
\t\tlogMinDelayReqInterval  0
\t\tpeerMeanPathDelay       0
\t\tdelayMechanism          1
sending: GET CURRENT_DATA_SET
\teab52b.fffe.8491cc-0 seq 1 RESPONSE MANAGEMENT CURRENT_DATA_SET
\t\tstepsRemoved     1
\t\toffsetFromMaster -446.0
\t\tmeanPathDelay    2772.0
sending: GET TIME_STATUS_NP
\teab52b.fffe.8491cc-0 seq 2 RESPONSE MANAGEMENT TIME_STATUS_NP
\t\tmaster_offset              -446
\t\tgmPresent                  true
\t\tgmIdentity                 ba0bde.fffe.b9c92a
"""


def test_pmc_answers_become_a_status():
    status = status_from_pmc(parse_pmc(PMC_SLAVE))
    assert status.port_state == "UNCALIBRATED"
    assert status.offset_from_master_ns == -446.0 and status.mean_path_delay_ns == 2772.0
    assert status.steps_removed == 1 and status.grandmaster == "ba0bde.fffe.b9c92a" and status.grandmaster_present
    assert status.line() == "PTP host UNCALIBRATED offset -446 ns path delay 2772 ns"


def test_phc2sys_log_lines():
    assert parse_phc2sys_line("phc2sys[2516.274]: CLOCK_REALTIME phc offset       -12 s2 freq   +3456 delay    500") \
        == (-12.0, "s2")
    assert parse_phc2sys_line("phc2sys[10.0]: eth0 sys offset 123456 s0 freq -20 delay 0") == (123456.0, "s0")
    assert parse_phc2sys_line("phc2sys[10.0]: reconfiguring after port state change") is None


def test_phc2sys_refusals_are_errors_not_offsets():
    """What phc2sys 3.1.1 printed here (tests below run it): without a PHC, and without the right to adjust."""
    assert parse_phc2sys_error("phc2sys[22559.459]: no suitable ports available") == "no suitable ports available"
    assert parse_phc2sys_error("phc2sys[22559.492]: interface sbs1v does not have a PHC") == \
        "interface sbs1v does not have a PHC"
    assert parse_phc2sys_error("phc2sys[22569.311]: failed to adjust the clock: Operation not permitted") == \
        "failed to adjust the clock: Operation not permitted"
    assert parse_phc2sys_error("phc2sys[22574.427]: Waiting for ptp4l...") == "Waiting for ptp4l"
    assert parse_phc2sys_error("phc2sys[2516.274]: CLOCK_REALTIME phc offset -12 s2 freq +3456 delay 500") is None
    monitor = PtpMonitor("/x", query=lambda: PtpStatus("SLAVE", offset_from_master_ns=-5.0))
    monitor.phc2sys_line("phc2sys[1.0]: no suitable ports available")
    status, events = monitor.poll()
    assert status.phc2sys_error == "no suitable ports available" and status.phc2sys_offset_ns is None
    assert "phc2sys: no suitable ports available" in status.line()
    monitor.phc2sys_line("phc2sys[2.0]: CLOCK_REALTIME phc offset -12 s2 freq +3456 delay 500")
    status, events = monitor.poll()  # measuring again: the error is gone
    assert status.phc2sys_error is None and status.phc2sys_offset_ns == -12.0 and events == []


def test_monitor_events_on_state_change_step_and_silence():
    answers = iter([
        PtpStatus("SLAVE", offset_from_master_ns=-20.0, mean_path_delay_ns=3000.0, grandmaster="a"),
        PtpStatus("SLAVE", offset_from_master_ns=15.0, mean_path_delay_ns=3000.0, grandmaster="a"),
        PtpStatus("SLAVE", offset_from_master_ns=2_000_015.0, mean_path_delay_ns=3000.0, grandmaster="a"),
        PtpStatus("LISTENING", offset_from_master_ns=0.0, grandmaster="b"),
        PtpStatus("UNREACHABLE", error="ptp4l at /x did not answer"),
        PtpStatus("LISTENING", grandmaster="b"),
    ])
    monitor = PtpMonitor("/x", step_ns=100_000, query=lambda: next(answers))
    monitor.phc2sys_line("phc2sys[1.0]: CLOCK_REALTIME phc offset 7 s2 freq +1 delay 500")
    seen = [monitor.poll()[1] for _ in range(6)]
    assert [e.message for e in seen[0]] == ["PTP host: SLAVE offset -20 ns path delay 3000 ns phc2sys offset 7 ns"]
    assert seen[1] == []  # 35 ns of wander is no step
    assert [(e.level, e.message) for e in seen[2]] == [("warning", "PTP host: offset stepped 15 -> 2000015 ns")]
    assert [e.message for e in seen[3]] == ["PTP host: port SLAVE -> LISTENING", "PTP host: grandmaster a -> b"]
    assert [e.message for e in seen[4]] == ["PTP host: ptp4l at /x did not answer"]
    assert [e.message for e in seen[5]] == ["PTP host: ptp4l answers again (LISTENING)"]
    assert monitor.status.phc2sys_offset_ns == 7.0 and monitor.status.phc2sys_state == "s2"


def test_query_of_a_ptp4l_that_is_not_there(tmp_path):
    if shutil.which("pmc") is None:
        pytest.skip("linuxptp's pmc is not installed (apt-get install linuxptp)")
    status = query_ptp4l(str(tmp_path / "no-ptp4l"), timeout_s=5.0)
    assert status.port_state == "UNREACHABLE" and not status.reachable
    assert "did not answer" in status.error


def test_receive_delay_distribution_and_jump():
    rd = ReceiveDelay(window=50, jump_ms=5.0, confirm=3)
    rng = np.random.default_rng(0)
    frame_end = np.arange(100) * 52_000_000
    msgs = []
    for k, t in enumerate(frame_end):
        delay_ms = 1.5 + rng.normal(0, 0.1) + (8.0 if k >= 60 else 0.0)  # the radar's clock steps 8 ms at frame 60
        msgs.append(rd.add(int(t + delay_ms * 1e6), int(t)))
    jumps = [(k, m) for k, m in enumerate(msgs) if m]
    assert len(jumps) == 1 and jumps[0][0] == 62  # confirmed by the third frame
    before, after = map(float, re.search(r"jumped from ([-\d.]+) ms to ([-\d.]+) ms", jumps[0][1]).groups())
    assert before == pytest.approx(1.5, abs=0.15) and after == pytest.approx(9.5, abs=0.15)
    stats = rd.stats()
    assert stats.median_ms == pytest.approx(9.5, abs=0.1) and stats.frames == 40
    assert rd.add(0, 5) is None  # a frame lost whole has no receive time


@pytest.mark.parametrize("rate", [0.5, 1.0 + 200e-6])
def test_clocks_at_another_rate_are_no_jump_but_a_step_on_top_is(rate):
    """A replay at 0.5x (the delay grows 52 ms a frame) or a radar clock 200 ppm off: a steady rate, no event;
    an 8 ms step on top of it is still one jump."""
    rd = ReceiveDelay(window=50, jump_ms=5.0, confirm=3)
    rng = np.random.default_rng(1)
    frame_end = np.arange(150) * 52_000_000
    msgs = []
    for k, t in enumerate(frame_end):
        host = t / rate + 1.5e6 + rng.normal(0, 0.1e6) + (8e6 if k >= 100 else 0.0)
        msgs.append(rd.add(int(host), int(t)))
    jumps = [k for k, m in enumerate(msgs) if m]
    assert jumps == [102]


def test_a_replay_on_a_loaded_machine_is_no_jump():
    """The demo's emulator at 0.5x on a busy machine: frames 52 ms apart in radar time, 104 ms at the host
    with +-15 ms of scatter (measured in a demo run). No event; a 150 ms step on top still is one."""
    rd = ReceiveDelay()
    rng = np.random.default_rng(3)
    frame_end = 1_700_000_000_000_000_000 + np.arange(400) * 52_000_000
    msgs = []
    for k, t in enumerate(frame_end):
        host = 1_795_643_000_000_000_000 + (t - frame_end[0]) * 2 + rng.uniform(-15e6, 15e6) + (150e6 if k >= 300 else 0)
        msgs.append(rd.add(int(host), int(t)))
    assert [k for k, m in enumerate(msgs) if m] == [300 + rd.confirm - 1]


def test_frames_late_by_different_amounts_are_latency_not_a_jump():
    """A host too busy to read its sockets for a moment: frames 20-60 ms late for a few frames at a time,
    then on time again. No event; a step of 8 ms held for the confirming frames still is one."""
    rd = ReceiveDelay(window=100, jump_ms=5.0)
    rng = np.random.default_rng(2)
    frame_end = np.arange(300) * 52_000_000
    msgs = []
    for k, t in enumerate(frame_end):
        late = rng.uniform(20, 60) if k % 40 in (10, 11, 12, 13, 14, 15) else 0.0
        step = 8.0 if k >= 270 else 0.0
        msgs.append(rd.add(int(t + (1.5 + rng.normal(0, 0.1) + late + step) * 1e6), int(t)))
    assert [k for k, m in enumerate(msgs) if m] == [270 + rd.confirm - 1]


def test_recording_holds_the_clock_state(tmp_path):
    rig = default_rig()
    path = tmp_path / "clock.h5"
    w = RecordingWriter(path, rig.radars, imu=rig.imu, adc_dtype="int16", clock_state=True)
    r = rig.radars[0]
    shape = (2, r.waveform.chirps_per_frame, r.waveform.n_rx, r.waveform.samples_per_chirp, 2)
    w.append_frames(r.name, np.zeros(shape, np.int16), [0, 52_000_000], [0, 1], [1, 2])
    w.append_frame_clock(r.name, [True, False])
    w.append_ptp(10, "SLAVE", -12.0, 2800.0, None)
    w.append_ptp(20, "LISTENING")
    w.close()
    with Recording(path) as rec:
        np.testing.assert_array_equal(rec.ptp_locked(r.name), [True, False])
        ptp = rec.ptp()
    assert list(ptp["port_state"]) == ["SLAVE", "LISTENING"]
    np.testing.assert_array_equal(ptp["time_ns"], [10, 20])
    assert ptp["offset_from_master_ns"][0] == -12.0 and np.isnan(ptp["offset_from_master_ns"][1])
    assert np.isnan(ptp["phc2sys_offset_ns"]).all()
    from acquisition.info import format_info, info

    text = format_info(info(path))
    assert "host PTP: 2 readings, port SLAVE -> LISTENING, offset from master median -12 ns" in text
    assert f"1 frames from a clock not PTP-locked (marked in /radar/{r.name}/ptp_locked)" in text


def _health(ptp: PtpStatus) -> Health:
    return Health({}, 0.0, 0, 0, 0, {}, 0, None, {}, ClockState({"left_front": True}, True, None), ptp=ptp)


def test_health_carries_the_ptp_state_over_the_bus():
    from acquisition.ptp import ReceiveDelayStats

    h = _health(PtpStatus("SLAVE", offset_from_master_ns=-12.0, mean_path_delay_ns=2800.0))
    h.receive_delay = {"left_front": ReceiveDelayStats(1.5, 2.5, 200)}
    h.unlocked_frames = {"left_front": 3}
    parts = h.to_parts()
    header = msgpack.unpackb(msgpack.packb(parts.fields, use_bin_type=True), raw=False)  # as the bus carries it
    back = Health.from_message(Message(parts.topic, 0, parts.sensor_time_ns, 0, header, []))
    assert back.ptp == h.ptp and back.receive_delay == h.receive_delay and back.unlocked_frames == {"left_front": 3}
    line = back.line()
    assert "PTP host SLAVE offset -12 ns path delay 2800 ns" in line
    assert "left_front receive-frame end 1.5 ms (p99 2.5)" in line and "left_front 3 frames unlocked" in line


# -- real ptp4l in two network namespaces -----------------------------------------------------------------
PTP4L_CONFIG = """[global]
uds_address {sock}
logAnnounceInterval -2
announceReceiptTimeout 2
logSyncInterval -3
logMinDelayReqInterval -3
{extra}
"""


def _run(*cmd):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=20)


@pytest.fixture
def veth_namespaces():
    """Two network namespaces joined by a veth pair (10.99.x.x exists only there). Skips where namespaces
    cannot be made."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2")
    if shutil.which("ptp4l") is None or shutil.which("pmc") is None:
        pytest.skip("linuxptp is not installed (apt-get install linuxptp)")
    tag = f"{os.getpid() % 100000}"
    master, slave = f"sbm{tag}", f"sbs{tag}"
    made = []
    try:
        for ns in (master, slave):
            res = _run("ip", "netns", "add", ns)
            if res.returncode != 0:
                pytest.skip(f"cannot make network namespaces here: {res.stderr.strip()}")
            made.append(ns)
        steps = [("ip", "link", "add", f"{master}v", "type", "veth", "peer", "name", f"{slave}v"),
                 ("ip", "link", "set", f"{master}v", "netns", master), ("ip", "link", "set", f"{slave}v", "netns", slave),
                 ("ip", "-n", master, "addr", "add", "10.99.35.1/24", "dev", f"{master}v"),
                 ("ip", "-n", slave, "addr", "add", "10.99.35.2/24", "dev", f"{slave}v"),
                 ("ip", "-n", master, "link", "set", f"{master}v", "up"), ("ip", "-n", slave, "link", "set", f"{slave}v", "up")]
        for cmd in steps:
            res = _run(*cmd)
            if res.returncode != 0:
                pytest.skip(f"cannot make a veth pair between namespaces: {' '.join(cmd)}: {res.stderr.strip()}")
        yield master, slave
    finally:
        for ns in made:  # the veth ends go with their namespaces
            _run("ip", "netns", "del", ns)


#: linuxptp's programs as the tests run them: without CAP_SYS_TIME (not even root may then set, step or slew a
#: clock: clock_adjtime fails with EPERM) and in an IPC namespace of their own (phc2sys's ntpshm servo writes
#: an NTP shared-memory segment, which a time daemon of the host might read).
NO_CLOCK_RIGHTS = ["unshare", "--ipc", "setpriv", "--inh-caps=-sys_time", "--bounding-set=-sys_time"]
CAP_SYS_TIME = 25  # include/uapi/linux/capability.h


def _ptp4l(ns: str, iface: str, config, log):
    # -S: software time stamps (a veth has no PHC). The namespaces share the host's clock: the master never
    # adjusts a clock, the slave runs free (free_running 1), and neither has the right to adjust one.
    return subprocess.Popen(["ip", "netns", "exec", ns, *NO_CLOCK_RIGHTS, "ptp4l", "-S", "-i", iface, "-f", str(config),
                             "-m"], stdout=log, stderr=subprocess.STDOUT)


def _realtime_minus_monotonic_ns() -> int:
    """What a step of CLOCK_REALTIME moves (CLOCK_MONOTONIC is never stepped)."""
    return time.clock_gettime_ns(time.CLOCK_REALTIME) - time.clock_gettime_ns(time.CLOCK_MONOTONIC)


def _start_master_and_slave(master: str, slave: str, tmp_path):
    """ptp4l master and free-running slave on the veth pair, the slave following (UNCALIBRATED); the processes
    and a PtpMonitor on the slave's socket."""
    (tmp_path / "m.cfg").write_text(PTP4L_CONFIG.format(sock=tmp_path / "m.sock", extra="priority1 1"))
    (tmp_path / "s.cfg").write_text(PTP4L_CONFIG.format(sock=tmp_path / "s.sock", extra="free_running 1\nslaveOnly 1"))
    m_log, s_log = open(tmp_path / "m.log", "w"), open(tmp_path / "s.log", "w")
    procs = [_ptp4l(master, f"{master}v", tmp_path / "m.cfg", m_log), _ptp4l(slave, f"{slave}v", tmp_path / "s.cfg", s_log)]
    return procs, PtpMonitor(str(tmp_path / "s.sock"))


def _stop(procs) -> None:
    for p in procs:
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def _wait_for(monitor, condition, timeout_s):
    deadline = time.monotonic() + timeout_s
    events = []
    while time.monotonic() < deadline:
        status, new = monitor.poll()
        events += new
        if condition(status):
            return status, events
        time.sleep(0.25)
    return None, events + [status]


def test_real_ptp4l_master_and_slave_over_a_veth_pair(veth_namespaces, tmp_path):
    master, slave = veth_namespaces
    procs = []
    try:
        started, monitor = _start_master_and_slave(master, slave, tmp_path)
        procs += started
        # A free-running slave never calls itself locked: it follows the master as UNCALIBRATED, measuring.
        status, events = _wait_for(monitor, lambda s: s.port_state in ("UNCALIBRATED", "SLAVE")
                                   and s.offset_from_master_ns not in (None, 0.0) and s.mean_path_delay_ns, 30.0)
        assert status is not None, (events[-1:], (tmp_path / "s.log").read_text())
        assert status.grandmaster_present and status.steps_removed == 1
        assert 0 < status.mean_path_delay_ns < 1e6  # software stamps over a veth: microseconds
        line = _health(status).line()
        assert f"PTP host {status.port_state} offset" in line and "path delay" in line
        assert any("LISTENING -> UNCALIBRATED" in e.message or "LISTENING -> SLAVE" in e.message for e in events)

        procs[0].terminate()  # the master goes away: the slave's announce timeout (0.5 s) ends its following
        procs[0].wait(10)
        status, events = _wait_for(monitor, lambda s: s.port_state not in ("UNCALIBRATED", "SLAVE"), 15.0)
        assert status is not None, (events[-1:], (tmp_path / "s.log").read_text())
        changes = [e for e in events if "PTP host: port" in e.message]
        assert changes and changes[0].level == "warning"
        assert changes[0].message.startswith("PTP host: port UNCALIBRATED -> ") or \
            changes[0].message.startswith("PTP host: port SLAVE -> ")
    finally:
        _stop(procs)


def _no_clock_rights_or_skip() -> None:
    missing = [c for c in ("unshare", "setpriv", "phc2sys") if shutil.which(c) is None]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed (util-linux, linuxptp): phc2sys is run only without the "
                    "right to touch the clock")


def test_phc2sys_as_the_tests_run_it_cannot_adjust_the_clock(tmp_path):
    """The guard every real phc2sys here runs under: no CAP_SYS_TIME. Even with the ntpshm servo (which
    leaves the clock to another process) phc2sys 3.1 sets the clock's frequency and status at start; without
    the right each such call fails with EPERM, and the clock stays as it was."""
    _no_clock_rights_or_skip()
    caps = subprocess.run([*NO_CLOCK_RIGHTS, "grep", "CapEff", "/proc/self/status"], capture_output=True, text=True,
                          timeout=10)
    if caps.returncode != 0:
        pytest.skip(f"cannot make a process without CAP_SYS_TIME here: {caps.stderr.strip()}")
    assert not int(caps.stdout.split()[1], 16) >> CAP_SYS_TIME & 1
    before = _realtime_minus_monotonic_ns()
    # CLOCK_REALTIME onto itself: the one thing phc2sys accepts without a PHC; it still tries to adjust.
    res = subprocess.run(["timeout", "3", *NO_CLOCK_RIGHTS, "phc2sys", "-s", "CLOCK_REALTIME", "-c", "CLOCK_REALTIME",
                          "-O", "0", "-E", "ntpshm", "-m", "-q"], capture_output=True, text=True, timeout=20)
    out = res.stdout + res.stderr
    assert "failed to adjust the clock: Operation not permitted" in out, out
    assert "Operation not permitted" in out and not re.search(r"offset\s+-?\d+ s\d", out)  # nothing to measure either
    assert abs(_realtime_minus_monotonic_ns() - before) < 500_000_000  # not stepped
    monitor = PtpMonitor("/x", query=lambda: PtpStatus("SLAVE", offset_from_master_ns=-5.0))
    for line in out.splitlines():
        monitor.phc2sys_line(line)
    status, _ = monitor.poll()
    assert status.phc2sys_error.endswith("Operation not permitted")  # its latest refusal, as health would say


def _phc2sys_beside(slave: str, tmp_path, log):
    """The real phc2sys in the slave's namespace, configured from its ptp4l (-a), on the ntpshm servo, without
    the right to touch a clock, its -m lines to ``log``."""
    return subprocess.Popen(["ip", "netns", "exec", slave, *NO_CLOCK_RIGHTS, "phc2sys", "-a", "-E", "ntpshm", "-R", "4",
                             "-z", str(tmp_path / "s.sock"), "-m", "-q"], stdout=log, stderr=subprocess.STDOUT)


def _phc2sys_in_the_slave_namespace(veth_namespaces, tmp_path):
    """Run ptp4l master and slave, then the real phc2sys beside the slave, its log followed by the poller
    as the daemon follows it: (statuses seen, events, phc2sys's log, the clock's step meanwhile ns)."""
    _no_clock_rights_or_skip()
    from acquisition.ptp import PtpPoller

    master, slave = veth_namespaces
    before = _realtime_minus_monotonic_ns()
    procs, monitor = _start_master_and_slave(master, slave, tmp_path)
    try:
        status, events = _wait_for(monitor, lambda s: s.port_state in ("UNCALIBRATED", "SLAVE"), 30.0)
        assert status is not None, (events[-1:], (tmp_path / "s.log").read_text())
        log_path = tmp_path / "phc2sys.log"
        log_path.write_text("")
        poller = PtpPoller(monitor, interval_s=0.25, phc2sys_log=str(log_path))
        with open(log_path, "a") as log:
            procs.append(_phc2sys_beside(slave, tmp_path, log))
        poller.start()
        seen, deadline = [], time.monotonic() + 10.0
        try:
            while time.monotonic() < deadline:
                for _, st, new in poller.drain():
                    seen.append(st)
                    events += new
                if any(st.phc2sys_offset_ns is not None for st in seen[-1:]) or \
                        (procs[-1].poll() is not None and any(st.phc2sys_error for st in seen[-1:])):
                    break
                time.sleep(0.1)
        finally:
            poller.stop()
    finally:
        _stop(procs)
    return seen, events, log_path.read_text(), _realtime_minus_monotonic_ns() - before


def test_real_phc2sys_beside_a_software_stamping_ptp4l_says_why_in_health(veth_namespaces, tmp_path):
    """phc2sys copies a PTP hardware clock to another clock; ptp4l on software stamps (-S) has none (it steers
    CLOCK_REALTIME itself). The real phc2sys, asked to configure itself from that ptp4l, says so, and health
    and /events carry what it said -- while the clock stays untouched."""
    seen, events, log, step_ns = _phc2sys_in_the_slave_namespace(veth_namespaces, tmp_path)
    assert abs(step_ns) < 500_000_000, step_ns
    if any(st.phc2sys_offset_ns is not None for st in seen):
        pytest.skip("this machine's veth has a PHC: phc2sys measured, see the next test")
    assert "no suitable ports available" in log, log
    last = seen[-1]
    assert last.phc2sys_error == "no suitable ports available" and last.phc2sys_offset_ns is None
    assert last.port_state in FOLLOWING_STATES  # ptp4l itself is fine
    assert "phc2sys: no suitable ports available" in _health(last).line()
    assert [e.message for e in events if e.message.startswith("PTP host: phc2sys")] == \
        ["PTP host: phc2sys: no suitable ports available"]


def test_real_phc2sys_offset_in_health(veth_namespaces, tmp_path):
    """Where phc2sys finds a PHC behind ptp4l's port it measures, and health shows its offset. A veth has none
    (and no card here has one): then this says exactly that and skips."""
    seen, events, log, step_ns = _phc2sys_in_the_slave_namespace(veth_namespaces, tmp_path)
    assert abs(step_ns) < 500_000_000, step_ns
    measured = [st for st in seen if st.phc2sys_offset_ns is not None]
    if not measured:
        import glob

        said = "; ".join(sorted({st.phc2sys_error for st in seen if st.phc2sys_error})) or log.strip()[-200:]
        phcs = sorted(glob.glob("/dev/ptp*"))
        where = f"this machine's PHCs ({', '.join(phcs)}) are not behind it" if phcs else "this machine has none (no /dev/ptp*)"
        pytest.skip("phc2sys measures only a PTP hardware clock (PHC) against another clock: ptp4l here runs on "
                    f"software time stamps (-S) on a veth, which has no PHC, and {where}; "
                    f"the real phc2sys -a said: {said!r}. Its offset lines are tested through their "
                    "format (test_phc2sys_log_lines, test_poller_takes_phc2sys_offsets_from_its_log_file)")
    assert f"phc2sys offset {measured[-1].phc2sys_offset_ns:.0f} ns" in _health(measured[-1]).line()


def test_recorder_marks_unlocked_frames_follows_receive_delay_and_records_ptp(tmp_path):
    """The recorder's side: a frame from an unlocked clock is stored and marked (and the loss and return of
    the lock are events), a receive delay that jumps is an event, the host's PTP readings go to /ptp with
    their events, and health carries all of it."""
    from acquisition.daemon import HealthMonitor
    from acquisition.messages import RadarFrameMessage
    from acquisition.processes import free_tcp_endpoint
    from acquisition.ptp import PtpEvent
    from acquisition.recorder import Recorder
    from drivers.radar.stream import RadarFrame
    from imaging.core.rig import AntennaArray, Rig
    from imaging.core.waveform import Waveform

    wf = Waveform(chirps_per_frame=8)
    rig = Rig((dataclasses.replace(default_rig().radars[0], waveform=wf, array=AntennaArray.uniform_tdm(wf)),),
              default_rig().imu)
    name = rig.radars[0].name
    path = tmp_path / "rec.h5"
    recorder = Recorder(path, rig, [free_tcp_endpoint()])
    try:
        iq = np.zeros((wf.chirps_per_frame, wf.n_rx, wf.samples_per_chirp, 2), np.int16)
        end = wf.frame_duration_ns
        for k in range(40):
            t = k * 52_000_000
            locked = not 20 <= k < 25
            delay = 2_000_000 if k < 30 else 12_000_000  # the path or the radar's clock steps by 10 ms at frame 30
            recorder._store_frame(RadarFrameMessage(name, RadarFrame(k, t, t + end + delay, True, 0, iq, locked)))
        recorder.record_ptp(PtpStatus("SLAVE", offset_from_master_ns=-12.0, mean_path_delay_ns=2800.0),
                            [PtpEvent("info", "PTP host: SLAVE offset -12 ns")], time_ns=123)
        health = HealthMonitor(recorder, {}).sample(0)
    finally:
        recorder.close()
    assert health.ptp.port_state == "SLAVE" and health.unlocked_frames == {name: 5}
    assert health.receive_delay[name].median_ms == pytest.approx(12.0)
    with Recording(path) as rec:
        locked = rec.ptp_locked(name)
        events = rec.events()
        ptp = rec.ptp()
    assert locked.size == 40 and np.flatnonzero(~locked).tolist() == [20, 21, 22, 23, 24]
    messages = [(source, level, message) for _, source, level, message in events]
    assert (f"radar.{name}", "warning", f"clock not PTP-locked: frames from 20 marked in /radar/{name}/ptp_locked") in messages
    assert (f"radar.{name}", "info", "clock PTP-locked again") in messages
    assert any(s == f"radar.{name}" and "jumped from 2.0 ms to 12.0 ms" in m for s, _, m in messages)
    assert ("ptp", "info", "PTP host: SLAVE offset -12 ns") in messages
    assert ptp["time_ns"].tolist() == [123] and list(ptp["port_state"]) == ["SLAVE"]


def test_poller_takes_phc2sys_offsets_from_its_log_file(tmp_path):
    """phc2sys serves no management requests: its -m lines, redirected to a file, are followed (from the
    end at start, a line half written waits), and its latest offset joins each status."""
    from acquisition.ptp import PtpPoller

    log_path = tmp_path / "phc2sys.log"
    log_path.write_text("phc2sys[1.0]: CLOCK_REALTIME phc offset 999999 s2 freq +1 delay 500\n")  # before: not taken
    monitor = PtpMonitor("/x", query=lambda: PtpStatus("SLAVE", offset_from_master_ns=-5.0))
    poller = PtpPoller(monitor, interval_s=0.05, phc2sys_log=str(log_path))
    follower = poller._phc2sys
    assert follower.new_lines() == []
    with open(log_path, "a") as fh:
        fh.write("phc2sys[2.0]: CLOCK_REALTIME phc offset -31 s2 freq +12 delay 480\nphc2sys[3.0]: CLOCK_REAL")
    poller.start()
    try:
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and not any(s.phc2sys_offset_ns == -31.0 for _, s, _ in poller.drain()):
            time.sleep(0.05)
        assert monitor.status.phc2sys_offset_ns == -31.0 and monitor.status.phc2sys_state == "s2"
        with open(log_path, "a") as fh:
            fh.write("TIME phc offset 7 s2 freq +12 delay 480\n")  # the half-written line completed
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and monitor.status.phc2sys_offset_ns != 7.0:
            time.sleep(0.05)
        assert monitor.status.phc2sys_offset_ns == 7.0
    finally:
        poller.stop()


def test_the_receive_delay_line_is_polyfits_within_a_stated_bound_and_keeps_the_last_window_in_order():
    """The line is fitted in closed form over the recent frames kept in arrays (not np.polyfit over a deque):
    the last ``window`` frames are the ones held, oldest first, however often the arrays wrap; the expected
    delay and scatter are np.polyfit's to 1e-9 ms plus 4e-15 of the largest delay (a few units in the last
    place of the delays themselves: 0.007 ms for a replay's 1.7e12 ms offset at 0.5x, 0.0004 ms for 1e11)."""
    rng = np.random.default_rng(7)
    for offset_ms, rate in ((1.5, 1.0), (1.5, 1.0 + 200e-6), (1.5, 0.5), (9.6e10, 1.0)):
        rd = ReceiveDelay(window=50, jump_ms=1e9)  # no jump: every frame is kept
        frame_end = 1_700_000_000_000_000_000 + np.arange(333) * 52_000_000
        host = frame_end / rate + offset_ms * 1e6 + rng.normal(0, 0.3e6, frame_end.size)
        for k, (t, h) in enumerate(zip(frame_end, host)):
            assert rd.add(int(h), int(t)) is None
            if k < 10 or k % 17:
                continue
            t_s, d_ms = rd._t_s[rd._start:rd._end], rd._d_ms[rd._start:rd._end]
            first = max(0, k + 1 - 50)
            np.testing.assert_array_equal(t_s, frame_end[first:k + 1] * 1e-9)
            np.testing.assert_array_equal(d_ms, (host[first:k + 1].astype(np.int64) - frame_end[first:k + 1]) * 1e-6)
            at = (frame_end[k] + 52_000_000) * 1e-9
            slope, intercept = np.polyfit(t_s - t_s[0], d_ms, 1)
            residual = d_ms - (intercept + slope * (t_s - t_s[0]))
            expected, scatter = rd._line(at)
            bound_ms = 1e-9 + 4e-15 * np.max(np.abs(d_ms))
            assert abs(expected - (intercept + slope * (at - t_s[0]))) <= bound_ms
            assert abs(scatter - 1.4826 * np.median(np.abs(residual))) <= bound_ms
        assert rd.stats().frames == 50
