"""Round trip: a recording replayed through emulated hardware (SRF1 on loopback UDP, Xbus on a pty, CAN on
python-can's virtual bus) into the drivers, over the bus into the recorder, comes back sample for sample
with no loss event, at real time and as fast as it goes."""

import threading
import time

import can
import numpy as np
import pytest
import zmq

from acquisition.bus import BusPublisher
from acquisition.driver_loops import can_driver_loop, imu_driver_loop, radar_driver_loop
from acquisition.recorder import Recorder
from acquisition.replay import imu_emulator, replay_can, replay_radar
from drivers.can_driver import CanDriver
from drivers.radar.srf1 import Srf1Stream
from drivers.radar.udp import UdpReceiver
from imaging.core.rig import rig_from_dict
from imaging.core.trajectory import PathWithTurns
from imaging.io.recording import Recording, RecordingWriter
from imaging.sim.imu_simulator import simulate_imu, simulate_radar_imu
from imaging.sim.robot_base_can import TRIGGER_ID, simulate_base_can
from imaging.sim.scene import DEFAULT_START_TIME_NS
from imaging.sim.simulator import simulate_frames
from imaging.sim.targets import PointTarget

RIG = rig_from_dict({"imu": {"rate_hz": 400.0},
                     "radar": {"left": {"mount_translation_m": [0.15, 0.2, 0.3], "mount_yaw_deg": 90.0,
                                        "waveform": {"chirps_per_frame": 32}}}})


def make_source(path, n_frames=30, rig=RIG):
    """A recording of radar "left" of ``rig``, the IMU and CAN; with the IMU on the radar's mount too where
    the rig declares one."""
    radar = rig.radar("left")
    wf = radar.waveform
    traj = PathWithTurns(segments=[("straight", 1.0)], speed_mps=0.4, t0_ns=DEFAULT_START_TIME_NS)
    ft = DEFAULT_START_TIME_NS + np.arange(n_frames, dtype=np.int64) * int(wf.frame_interval_s * 1e9)
    adc = simulate_frames(radar, traj, [PointTarget((0.0, 2.0, 0.3))], ft, snr_db=20, rng=np.random.default_rng(0))
    iq = np.round(np.stack([adc.real, adc.imag], -1) * 400).astype(np.int16)  # an ADC with some headroom
    imu = simulate_imu(traj, rig.imu, ft[0], ft[-1], rng=np.random.default_rng(1))
    with RecordingWriter(path, [radar], imu=rig.imu, adc_dtype="int16", truth=False) as w:
        w.append_frames("left", iq, ft, np.arange(n_frames), ft)
        w.append_imu(imu.time_ns, imu.gyro_radps.astype(np.float32), imu.accel_mps2.astype(np.float32), imu.counter, imu.time_ns)
        if radar.imu is not None:
            ri = simulate_radar_imu(traj, radar, ft[0], ft[-1], rng=np.random.default_rng(2))
            w.append_radar_imu("left", ri.time_ns, ri.gyro_radps.astype(np.float32), ri.accel_mps2.astype(np.float32),
                               ri.counter, ri.time_ns)
        w.append_trigger(ft[0], "sync_box")
        base = simulate_base_can(traj, ft[0], ft[-1], trigger_time_ns=int(ft[0]))
        w.append_can(base["time_ns"], base["arbitration_id"], base["dlc"], base["data"])
    return iq, imu


@pytest.mark.parametrize("speed", [1.0, None], ids=["real-time", "fastest"])
def test_round_trip_sample_for_sample(tmp_path, speed):
    src = tmp_path / "source.h5"
    iq, imu = make_source(src)
    ctx = zmq.Context()
    # One publisher per driver, as one process per device has (a ZeroMQ socket is not shared between threads).
    pubs = {k: BusPublisher("tcp://127.0.0.1:0", context=ctx) for k in ("radar", "imu", "can")}
    rec = Recorder(tmp_path / "again.h5", RIG, [p.endpoint for p in pubs.values()], context=ctx)
    stop = threading.Event()
    rx = UdpReceiver()
    channel = f"round-trip-{speed}"
    can_rx = CanDriver(can.Bus(interface="virtual", channel=channel), trigger_id=TRIGGER_ID)
    can_tx = can.Bus(interface="virtual", channel=channel)
    with Recording(src) as source:
        emu = imu_emulator(source, speed=speed)
        threads = [threading.Thread(target=radar_driver_loop, args=(rx, "left", Srf1Stream(iq.shape[1:4]), pubs["radar"], stop)),
                   threading.Thread(target=imu_driver_loop, args=(emu.port, pubs["imu"], stop, int(source.triggers()[0]))),
                   threading.Thread(target=can_driver_loop, args=(can_rx, pubs["can"], stop))]
        for t in threads:
            t.start()
        time.sleep(0.3)  # the drivers open their ports first, as on the robot (opening a serial port flushes it)
        emu.start()
        t0 = time.monotonic()
        sent_can = replay_can(source, can_tx, speed)
        replay_radar(source, "left", rx.address, speed=speed)
        emu.done.wait(30)
        sending_s = time.monotonic() - t0
        deadline = time.monotonic() + 10
        n_can = source.can()["time_ns"].size
        while time.monotonic() < deadline:
            rec.step(timeout_ms=50)
            if rec.frames["left"] == iq.shape[0] and rec.imu_samples == imu.time_ns.size and rec.can_frames == n_can:
                break
        stop.set()
        for t in threads:
            t.join(5)
        while rec.step(timeout_ms=200):
            pass
    rec.close()
    emu.close()
    rx.close()
    can_rx.close()
    can_tx.shutdown()
    for p in pubs.values():
        p.close()
    ctx.term()
    if speed is None:  # really faster than the recording lasts (1.5 s of frames)
        assert sending_s < 1.0, sending_s
    with Recording(tmp_path / "again.h5") as again, Recording(src) as source:
        np.testing.assert_array_equal(again.file["radar/left/adc"][()], iq)
        np.testing.assert_array_equal(again.frame_time_ns("left"), source.frame_time_ns("left"))
        assert again.valid("left").all()
        got = again.imu()
        np.testing.assert_array_equal(got["time_ns"], imu.time_ns)
        np.testing.assert_array_equal(got["gyro_radps"], imu.gyro_radps.astype(np.float32))
        np.testing.assert_array_equal(got["accel_mps2"], imu.accel_mps2.astype(np.float32))
        np.testing.assert_array_equal(got["counter"], imu.counter)
        # CAN: every frame, raw; the trigger frame's PTP time comes through as a trigger too.
        want, back = source.can(), again.can()
        assert sent_can == want["time_ns"].size > 50
        for k in ("arbitration_id", "dlc", "data"):
            np.testing.assert_array_equal(back[k], want[k])
        assert sorted(again.triggers().tolist()) == sorted([int(imu.time_ns[0]), int(source.frame_time_ns("left")[0])])
        assert again.file["events/message"].shape[0] == 0  # no loss, no event
