"""A live frame's antennas placed on a sampled trajectory in one kernel call: positions and looks only.

The "polar" map needs each profile's TX and RX position and its horizontal look, nothing else of
``imaging.core.geometry.antenna_track`` (no velocities, no angular rate, no acceleration). Placing a frame's
64 chirp groups by ``antenna_track`` on a ``SampledTrajectory`` took about forty small numpy operations
(the sample's slerp, the lever arms' einsums and cross products, the repeats for the RX channels), a sixth of a
live frame's CPU (benchmarks/stripmap_presum.py). ``place_profiles`` does the same arithmetic, in the same
order, point by point in one call: the same numbers to float64 rounding (tests/test_stripmap_placement.py
checks it against ``antenna_track``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from imaging.core.rig import RadarConfig
from imaging.core.trajectory import SampledTrajectory
from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)


def place_profiles(radar: RadarConfig, trajectory: SampledTrajectory, time_ns: np.ndarray, tx_index: np.ndarray,
                   sum_rx: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each profile's TX and RX position and horizontal unit look, profiles chirp group by chirp group, RX
    channel by channel within a group (as the pre-summed samples [G, n_rx, n] flatten).

    Parameters
    ----------
    time_ns : ndarray, int64, shape (G,)
        The chirp groups' times on the radar's clock, ns.
    tx_index : ndarray, int, shape (G,)
        The TX of each group.
    sum_rx : bool
        One profile per group, at the RX channels' centroid (``StripMap.add_frames``'s ``sum_rx``).

    Returns
    -------
    tx_m, rx_m : ndarray, float64, shape (G x R, 3)
        World positions, m (R = n_rx, or 1 with ``sum_rx``).
    look : ndarray, float64, shape (G x R, 2)
        The boresight's horizontal direction, unit length.
    """
    time_ns = np.asarray(time_ns, np.int64).ravel()
    offset_ns = 0 if radar.calibration is None else int(round(radar.calibration.time_offset_s * 1e9))
    # seconds from the trajectory's start as SampledTrajectory.sample computes them (integer ns first)
    t_s = (time_ns - np.int64(offset_ns) - np.int64(trajectory.t0_ns)).astype(np.float64) * 1e-9
    mount = radar.mount
    tx_body = np.ascontiguousarray(mount.to_body(radar.array.tx_positions_m)[np.asarray(tx_index).ravel()])
    rx_body = np.ascontiguousarray(mount.to_body(radar.array.rx_positions_m))
    per = 1 if sum_rx else rx_body.shape[0]
    tx_m, rx_m, look = np.empty((t_s.size * per, 3)), np.empty((t_s.size * per, 3)), np.empty((t_s.size * per, 2))
    _place(tx_m, rx_m, look, t_s, trajectory._t, trajectory.position_m, trajectory._quat, trajectory._step_rotvec,
           trajectory._dt, tx_body, rx_body, np.ascontiguousarray(mount.boresight_body), sum_rx)
    return tx_m, rx_m, look


@numba.njit(cache=True, nogil=True)
def _place(tx_out, rx_out, look_out, t_s, knots, pos, quat, step_rotvec, dt, tx_body, rx_body, bore_body, sum_rx):
    """``place_profiles``' arithmetic per chirp group: the pose as ``SampledTrajectory.sample`` interpolates it
    (position linearly, attitude by R_k exp(u log(R_k^T R_{k+1}))), its matrix as ``quaternion.to_matrix``, the
    lever arms rotated and added as ``antenna_track``."""
    n_rx = rx_body.shape[0]
    per = 1 if sum_rx else n_rx
    last = knots.size - 1
    for g in range(t_s.size):
        t = min(max(t_s[g], knots[0]), knots[last])
        k = min(max(np.searchsorted(knots, t, side="right") - 1, 0), dt.size - 1)
        u = (t - knots[k]) / dt[k]
        p0 = pos[k, 0] + u * (pos[k + 1, 0] - pos[k, 0])
        p1 = pos[k, 1] + u * (pos[k + 1, 1] - pos[k, 1])
        p2 = pos[k, 2] + u * (pos[k + 1, 2] - pos[k, 2])
        vx, vy, vz = u * step_rotvec[k, 0], u * step_rotvec[k, 1], u * step_rotvec[k, 2]
        angle = math.sqrt(vx * vx + vy * vy + vz * vz)
        half = 0.5 * angle
        scale = math.sin(half) / angle if angle > 1e-4 else 0.5 - angle ** 2 / 48.0
        qx, qy, qz, qw = vx * scale, vy * scale, vz * scale, math.cos(half)
        px, py, pz, pw = quat[k, 0], quat[k, 1], quat[k, 2], quat[k, 3]
        x = pw * qx + px * qw + py * qz - pz * qy
        y = pw * qy - px * qz + py * qw + pz * qx
        z = pw * qz + px * qy - py * qx + pz * qw
        w = pw * qw - px * qx - py * qy - pz * qz
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
        x2, y2, z2, w2 = x * x, y * y, z * z, w * w
        xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
        r = np.empty((3, 3))
        r[0, 0] = x2 - y2 - z2 + w2
        r[1, 0] = 2 * (xy + zw)
        r[2, 0] = 2 * (xz - yw)
        r[0, 1] = 2 * (xy - zw)
        r[1, 1] = -x2 + y2 - z2 + w2
        r[2, 1] = 2 * (yz + xw)
        r[0, 2] = 2 * (xz + yw)
        r[1, 2] = 2 * (yz - xw)
        r[2, 2] = -x2 - y2 + z2 + w2
        bx = r[0, 0] * bore_body[0] + r[0, 1] * bore_body[1] + r[0, 2] * bore_body[2]
        by = r[1, 0] * bore_body[0] + r[1, 1] * bore_body[1] + r[1, 2] * bore_body[2]
        bl = math.sqrt(bx * bx + by * by)
        for j in range(per):
            i = g * per + j
            for a in range(3):
                tx_out[i, a] = (p0, p1, p2)[a] + (r[a, 0] * tx_body[g, 0] + r[a, 1] * tx_body[g, 1]
                                                   + r[a, 2] * tx_body[g, 2])
                if sum_rx:
                    acc = 0.0
                    for c in range(n_rx):
                        acc += (p0, p1, p2)[a] + (r[a, 0] * rx_body[c, 0] + r[a, 1] * rx_body[c, 1]
                                                  + r[a, 2] * rx_body[c, 2])
                    rx_out[i, a] = acc / n_rx
                else:
                    rx_out[i, a] = (p0, p1, p2)[a] + (r[a, 0] * rx_body[j, 0] + r[a, 1] * rx_body[j, 1]
                                                      + r[a, 2] * rx_body[j, 2])
            look_out[i, 0] = bx / bl
            look_out[i, 1] = by / bl
