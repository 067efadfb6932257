"""Shared fixtures: small simulated passes, made once per session in a temporary folder."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from imaging.core.rig import default_rig  # noqa: E402
from imaging.core.trajectory import StraightLine  # noqa: E402
from imaging.sim.scene import DEFAULT_START_TIME_NS, Scene  # noqa: E402
from imaging.sim.targets import PointTarget  # noqa: E402

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
RADAR = "left_front"
R0 = 2.0
LEFT_FRONT_OFFSET = np.array([0.15, 0.20, 0.30])  # mount of the left-front radar in the body frame


def point_pass(speed_mps: float, duration_s: float, origin=(0.0, 0.0), snr_db=None, vibration=None, seed=0) -> Scene:
    """A straight pass of the left-front radar broadside to one point target at r0 = 2 m, mid-run.

    ``origin`` shifts the whole scene (trajectory and target) in x, y.
    """
    ox, oy = origin
    start_x = ox - LEFT_FRONT_OFFSET[0] - speed_mps * duration_s / 2
    trajectory = StraightLine(start_m=(start_x, oy - LEFT_FRONT_OFFSET[1], 0.0), speed_mps=speed_mps, t0_ns=DEFAULT_START_TIME_NS)
    return Scene(
        name="test_point_pass", rig=default_rig(), trajectory=trajectory,
        targets=[PointTarget((ox, oy + R0, LEFT_FRONT_OFFSET[2]))], duration_s=duration_s, radars=[RADAR],
        snr_db=snr_db, vibration=vibration, seed=seed,
    )


@pytest.fixture(scope="session")
def sim_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("sim")


@pytest.fixture(scope="session")
def pass_recordings(sim_dir):
    """Noise-free passes at 0.4 and 1.0 m/s, long enough for a 0.34 m aperture around broadside."""
    from imaging.sim.simulator import simulate_recording

    paths = {}
    for speed in (0.4, 1.0):
        path = sim_dir / f"pass_{speed}.h5"
        simulate_recording(point_pass(speed, duration_s=0.5 / speed + 0.2), path)
        paths[speed] = path
    return paths


def send_frame_and_poses(frames_pub, poses_pub, radar: str, k: int, iq, times, truth) -> None:
    """Frame ``k`` of ``iq`` (complex or int16 I/Q pairs) as radar ``radar``'s live frame on ``frames_pub``, and
    the true poses around it (50 ms before to 110 ms after its start, every 10 ms) on ``poses_pub``: what the
    drivers and the odometry send a strip-map worker."""
    import time

    from acquisition.messages import PoseBatch, RadarFrameMessage
    from drivers.radar.stream import RadarFrame

    frame = iq[k]
    pub_iq = np.stack([frame.real, frame.imag], -1).round().astype(np.int16) if frame.dtype.kind == "c" else frame
    frames_pub.send(RadarFrameMessage(radar, RadarFrame(k, int(times[k]), time.time_ns(), True, 0, pub_iq)))
    t = np.arange(times[k] - 50_000_000, times[k] + 110_000_000, 10_000_000, dtype=np.int64)
    s = truth.sample(t)
    poses_pub.send(PoseBatch(t, s.position_m, s.orientation_xyzw, s.velocity_mps))
