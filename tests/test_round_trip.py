"""Round trip: a recording replayed through emulated hardware (SRF1 on loopback UDP, Xbus on a pty)
into the drivers, over the bus into the recorder, comes back sample for sample with no loss event."""

import threading
import time

import numpy as np
import zmq

from acquisition.bus import BusPublisher
from acquisition.pipeline import imu_driver_loop, imu_emulator, radar_driver_loop, replay_radar
from acquisition.recorder import Recorder
from drivers.imu import ImuDriver
from drivers.udp import UdpReceiver
from imaging.imu_simulator import simulate_imu
from imaging.recording import Recording, RecordingWriter
from imaging.rig import rig_from_dict
from imaging.scene import DEFAULT_START_TIME_NS
from imaging.simulator import simulate_frames
from imaging.targets import PointTarget
from imaging.trajectory import PathWithTurns

RIG = rig_from_dict({"imu": {"rate_hz": 400.0},
                     "radar": {"left": {"mount_translation_m": [0.15, 0.2, 0.3], "mount_yaw_deg": 90.0,
                                        "waveform": {"chirps_per_frame": 32}}}})


def make_source(path, n_frames=30):
    radar = RIG.radar("left")
    wf = radar.waveform
    traj = PathWithTurns(segments=[("straight", 1.0)], speed_mps=0.4, t0_ns=DEFAULT_START_TIME_NS)
    ft = DEFAULT_START_TIME_NS + np.arange(n_frames, dtype=np.int64) * int(wf.frame_interval_s * 1e9)
    adc = simulate_frames(radar, traj, [PointTarget((0.0, 2.0, 0.3))], ft, snr_db=20, rng=np.random.default_rng(0))
    iq = np.round(np.stack([adc.real, adc.imag], -1) * 400).astype(np.int16)  # an ADC with some headroom
    imu = simulate_imu(traj, RIG.imu, ft[0], ft[-1], rng=np.random.default_rng(1))
    with RecordingWriter(path, [radar], imu=RIG.imu, adc_dtype="int16", truth=False) as w:
        w.append_frames("left", iq, ft, np.arange(n_frames), ft)
        w.append_imu(imu.time_ns, imu.gyro_radps.astype(np.float32), imu.accel_mps2.astype(np.float32), imu.counter, imu.time_ns)
        w.append_trigger(ft[0], "sync_box")
    return iq, imu


def test_round_trip_sample_for_sample(tmp_path):
    src = tmp_path / "source.h5"
    iq, imu = make_source(src)
    ctx = zmq.Context()
    # One publisher per driver, as one process per device has (a ZeroMQ socket is not shared between threads).
    pub_radar = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    pub_imu = BusPublisher("tcp://127.0.0.1:0", context=ctx)
    rec = Recorder(tmp_path / "again.h5", RIG, [pub_radar.endpoint, pub_imu.endpoint], context=ctx)
    stop = threading.Event()
    rx = UdpReceiver()
    shape = iq.shape[1:]
    with Recording(src) as source:
        emu = imu_emulator(source, speed=4.0)
        driver = ImuDriver(emu.port, trigger_time_ns=int(source.triggers()[0]))
        threads = [threading.Thread(target=radar_driver_loop, args=(rx, "left", shape, pub_radar, stop)),
                   threading.Thread(target=imu_driver_loop, args=(driver, pub_imu, stop))]
        time.sleep(0.3)
        for t in threads:
            t.start()
        emu.start()
        replay_radar(source, "left", rx.address, speed=4.0)
        emu.done.wait(10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            rec.step(timeout_ms=50)
            if rec.frames["left"] == iq.shape[0] and rec.imu_samples == imu.time_ns.size:
                break
        stop.set()
        for t in threads:
            t.join(5)
        while rec.step(timeout_ms=200):
            pass
    rec.close()
    emu.close()
    driver.close()
    rx.close()
    pub_radar.close()
    pub_imu.close()
    ctx.term()
    with Recording(tmp_path / "again.h5") as again:
        np.testing.assert_array_equal(again.file["radar/left/adc"][()], iq)
        np.testing.assert_array_equal(again.frame_time_ns("left"), Recording(src).frame_time_ns("left"))
        assert again.valid("left").all()
        got = again.imu()
        np.testing.assert_array_equal(got["time_ns"], imu.time_ns)
        np.testing.assert_array_equal(got["gyro_radps"], imu.gyro_radps.astype(np.float32))
        np.testing.assert_array_equal(got["accel_mps2"], imu.accel_mps2.astype(np.float32))
        np.testing.assert_array_equal(got["counter"], imu.counter)
        assert again.triggers().tolist() == [int(imu.time_ns[0])]
        assert again.file["events/message"].shape[0] == 0  # no loss, no event
