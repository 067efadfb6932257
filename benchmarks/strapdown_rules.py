"""Strapdown integration rules against the truth, without the filter: dead reckoning on exact IMU data of the
7-lap odometry drive (benchmarks/odometry.py), restarted from the true state every window.

    python benchmarks/strapdown_rules.py [--quick]

Two kinds of IMU sample, neither with noise or bias:

- point: the rate and specific force AT the sample time, as imaging/sim/imu_simulator.py gives them;
- average: their mean over the interval that ENDS at the sample time (32 sub-samples), what an IMU that
  integrates or averages internally delivers (an Xsens MTi's rate of turn and acceleration come out of its
  strapdown integration; an ADIS16448 at 204.8 Hz averages 4 samples of its 819.2 Hz clock).

Four rules for the interval [t_k, t_k+1]:

- start: sample k held, rotated by the attitude at the interval's start (before f53ede5);
- mid: sample k held, the specific force rotated by the attitude at the interval's midpoint (rio/strapdown.py);
- trap: the mean of samples k and k+1 (trapezoid), midpoint attitude;
- own: sample k+1, the sample stamped at the interval's end, midpoint attitude.

Writes docs/results/strapdown_rules.json: RMS over windows of the horizontal position, velocity and yaw error
at each window's end.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from imaging.core.constants import GRAVITY_MPS2  # noqa: E402
from odometry import long_drive  # noqa: E402
from results_file import load_average, write_results  # noqa: E402
from rio.strapdown import _exp_so3_nb  # noqa: E402

RESULTS = ROOT / "docs" / "results"
RULES = ("start", "mid", "trap", "own")
RATE_HZ = 400.0
SUBSAMPLES = 32


@numba.njit(cache=True)
def _dead_reckon(rule, p, v, R, f, w, k0, k1, dt):
    """Propagate from sample k0 to k1 with ``rule`` (index into RULES); returns p, v, R at k1."""
    g = np.array([0.0, 0.0, GRAVITY_MPS2])
    for k in range(k0, k1):
        if rule == 0 or rule == 1:
            fk, wk = f[k], w[k]
        elif rule == 2:
            fk, wk = 0.5 * (f[k] + f[k + 1]), 0.5 * (w[k] + w[k + 1])
        else:
            fk, wk = f[k + 1], w[k + 1]
        if rule == 0:
            a = R @ fk - g
        else:
            a = R @ (_exp_so3_nb(0.5 * wk * dt) @ fk) - g
        p = p + v * dt + 0.5 * a * dt * dt
        v = v + a * dt
        R = R @ _exp_so3_nb(wk * dt)
    return p, v, R


def imu_samples(trajectory, t0_ns: int, n: int):
    """Point samples at t0 + k/rate and averages over the interval ending there (body frame = IMU frame)."""
    dt = 1.0 / RATE_HZ
    t = t0_ns + np.round(np.arange(n) * dt * 1e9).astype(np.int64)
    s = trajectory.sample(t)
    rot = s.rotation.as_matrix()
    g = np.array([0.0, 0.0, GRAVITY_MPS2])
    f_point = np.einsum("nji,nj->ni", rot, s.acceleration_mps2 + g)
    sub_t = t0_ns + np.round((np.arange(n * SUBSAMPLES) - SUBSAMPLES + 0.5) * dt / SUBSAMPLES * 1e9).astype(np.int64)
    ss = trajectory.sample(sub_t)
    f_sub = np.einsum("nji,nj->ni", ss.rotation.as_matrix(), ss.acceleration_mps2 + g)
    f_avg = f_sub.reshape(n, SUBSAMPLES, 3).mean(axis=1)
    w_avg = ss.angular_velocity_body_radps.reshape(n, SUBSAMPLES, 3).mean(axis=1)
    return s, rot, {"point": (f_point, s.angular_velocity_body_radps), "average": (f_avg, w_avg)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the first 60 s only")
    ap.add_argument("--window-s", type=float, default=10.0)
    args = ap.parse_args()
    started_load = load_average()
    scene = long_drive(7, seed=10)
    duration_s = 63.0 if args.quick else scene.duration_s
    n = int(duration_s * RATE_HZ)
    truth, rot, kinds = imu_samples(scene.trajectory, scene.start_time_ns, n)
    win = int(args.window_s * RATE_HZ)
    starts = list(range(int(3.0 * RATE_HZ), n - win - 1, win))  # from the end of the 3 s standstill
    out = {"drive": scene.name, "imu_rate_hz": RATE_HZ, "window_s": args.window_s, "windows": len(starts),
           "subsamples_per_average": SUBSAMPLES, "rules": {}}
    for kind, (f, w) in kinds.items():
        f = np.ascontiguousarray(f)
        w = np.ascontiguousarray(w)
        for i, rule in enumerate(RULES):
            err = []
            for k in starts:
                p, v, R = _dead_reckon(i, truth.position_m[k].copy(), truth.velocity_mps[k].copy(), rot[k].copy(),
                                       f, w, k, k + win, 1.0 / RATE_HZ)
                R_err = rot[k + win].T @ R
                yaw = math.atan2(R_err[1, 0] - R_err[0, 1], R_err[0, 0] + R_err[1, 1])  # level: a turn about z
                err.append(np.r_[p[:2] - truth.position_m[k + win, :2], v[:2] - truth.velocity_mps[k + win, :2], yaw])
            e = np.array(err)
            row = {"position_rms_mm": 1e3 * float(np.sqrt(np.mean(np.sum(e[:, 0:2] ** 2, axis=1)))),
                   "velocity_rms_mmps": 1e3 * float(np.sqrt(np.mean(np.sum(e[:, 2:4] ** 2, axis=1)))),
                   "yaw_rms_mdeg": 1e3 * math.degrees(float(np.sqrt(np.mean(e[:, 4] ** 2)))),
                   "position_max_mm": 1e3 * float(np.max(np.linalg.norm(e[:, 0:2], axis=1))),
                   "yaw_max_mdeg": 1e3 * math.degrees(float(np.max(np.abs(e[:, 4]))))}
            out["rules"][f"{kind}_{rule}"] = row
            print(f"{kind:8s} {rule:6s} position {row['position_rms_mm']:7.3f} mm  velocity {row['velocity_rms_mmps']:6.3f} mm/s"
                  f"  yaw {row['yaw_rms_mdeg']:7.3f} mdeg  (RMS over {len(starts)} windows of {args.window_s:.0f} s)")
    out["load_average_1min"] = os.getloadavg()[0]
    name = "strapdown_rules_quick" if args.quick else "strapdown_rules"
    write_results(name, out, started_load=started_load)
    print(f"wrote {RESULTS / (name + '.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
