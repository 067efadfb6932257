"""CAN traffic of the robot base: the sync box's trigger frame and wheel-speed frames from a trajectory.

The wheel frame (id ``WHEEL_SPEED_ID``) carries the left and right wheel speeds of a differential drive as
little-endian int32 in mm/s; the trigger frame (id ``TRIGGER_ID``) the PTP time of the trigger edge as a
little-endian u64. Times are CAN receive times on the PTP base.
"""

from __future__ import annotations

import numpy as np

from imaging.core.constants import CAN_TRIGGER_ID
from imaging.core.trajectory import Trajectory

TRIGGER_ID = CAN_TRIGGER_ID
WHEEL_SPEED_ID = 0x201
#: Delay from the bus to the host's receive time stamp.
CAN_RECEIVE_LATENCY_NS = 300_000


def simulate_base_can(trajectory: Trajectory, start_ns: int, end_ns: int, rate_hz: float = 50.0, track_m: float = 0.37,
                      trigger_time_ns: int | None = None) -> dict[str, np.ndarray]:
    """Frames as /can stores them: ``time_ns`` [K], ``arbitration_id`` [K], ``dlc`` [K], ``data`` [K, 64].

    Parameters
    ----------
    trajectory : Trajectory
        Body motion; forward speed and yaw rate give the wheel speeds.
    start_ns, end_ns : int
        PTP time span, ns.
    rate_hz : float
        Wheel frame rate.
    track_m : float
        Distance between the wheels.
    trigger_time_ns : int, optional
        Adds the trigger frame for this edge (sent when it happens).
    """
    step = int(round(1e9 / rate_hz))
    t = np.arange(start_ns, end_ns, step, dtype=np.int64)
    s = trajectory.sample(t)
    forward = np.einsum("nij,nj->ni", s.rotation.inv().as_matrix(), s.velocity_mps)[:, 0]
    yaw_rate = s.angular_velocity_body_radps[:, 2]
    wheels_mmps = np.stack([forward - yaw_rate * track_m / 2, forward + yaw_rate * track_m / 2], axis=1) * 1e3
    data = np.zeros((t.size, 64), np.uint8)
    data[:, :8] = np.round(wheels_mmps).astype("<i4").view(np.uint8).reshape(-1, 8)
    ids = np.full(t.size, WHEEL_SPEED_ID, np.uint32)
    dlc = np.full(t.size, 8, np.uint8)
    if trigger_time_ns is not None:
        k = int(np.searchsorted(t, trigger_time_ns))
        row = np.zeros((1, 64), np.uint8)
        row[0, :8] = np.frombuffer(np.int64(trigger_time_ns).astype("<u8").tobytes(), np.uint8)
        t = np.insert(t, k, trigger_time_ns)
        ids = np.insert(ids, k, TRIGGER_ID)
        dlc = np.insert(dlc, k, 8)
        data = np.insert(data, k, row, axis=0)
    return {"time_ns": t + CAN_RECEIVE_LATENCY_NS, "arbitration_id": ids, "dlc": dlc, "data": data}
