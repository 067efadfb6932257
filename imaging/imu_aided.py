"""The radar's displacement along its boresight from an IMU on the radar's own mount.

A vibration of the radar against the robot (a few hertz, a fraction of a millimetre) is invisible to the
robot's IMU and to the odometry, but an accelerometer on the radar feels it: along the boresight (the radar
IMU's x axis) its specific force is the vibration's acceleration plus slow terms (the robot's own lateral
acceleration, gravity through a tilt, the sensor's bias). A zero-phase high-pass takes the slow terms out,
and two integrations over the aperture give the displacement, whose offset and drift (arbitrary, like
autofocus's) are set to zero. What the high-pass removes, a vibration below its corner included, is left
to autofocus, which takes this displacement as its starting track.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from imaging.core.track_error import TrackError, remove_line


def boresight_track_from_imu(time_ns: np.ndarray, accel_mps2: np.ndarray, time_window_ns: tuple[int, int],
                             time_origin_ns: int, highpass_hz: float = 2.0) -> TrackError:
    """Displacement along the boresight over ``time_window_ns`` from the radar IMU's specific force.

    Parameters
    ----------
    time_ns : ndarray, int64, shape (N,)
        Sample times (the sensors' common time base).
    accel_mps2 : ndarray, shape (N, 3)
        Specific force in the radar's axes (x along the boresight), m/s^2.
    time_window_ns : (start, stop)
        The aperture: where the displacement is wanted.
    time_origin_ns : int
        The TrackError's time origin (the image's first frame).
    highpass_hz : float
        Corner of the 4th-order zero-phase Butterworth high-pass that removes slow accelerations and bias.

    Returns
    -------
    TrackError
        ``method`` "imu", displacement at the IMU's samples within the window.
    """
    t = np.asarray(time_ns, np.int64)
    f = np.asarray(accel_mps2, float)[:, 0]
    if t.size < 16:
        raise ValueError(f"the radar's IMU has {t.size} samples; too few to integrate")
    rate = 1e9 / float(np.median(np.diff(t)))
    if not 0 < highpass_hz < 0.5 * rate:
        raise ValueError(f"highpass_hz {highpass_hz} must lie between 0 and half the IMU's rate ({0.5 * rate:g} Hz)")
    # Filter over the window and a margin of a few corner periods either side (the filter's settling).
    margin = int(4e9 / highpass_hz)
    near = (t >= time_window_ns[0] - margin) & (t <= time_window_ns[1] + margin)
    tt, ff = t[near], f[near]
    if tt.size < 16:
        raise ValueError("the radar's IMU has no samples around the aperture")
    sos = scipy.signal.butter(4, highpass_hz, "highpass", fs=rate, output="sos")
    hp = scipy.signal.sosfiltfilt(sos, ff - ff.mean())
    inside = (tt >= time_window_ns[0]) & (tt <= time_window_ns[1])
    if inside.sum() < 4:
        raise ValueError("the radar's IMU has fewer than 4 samples within the aperture")
    ts = (tt[inside] - np.int64(time_origin_ns)) * 1e-9
    a = hp[inside]
    dt = np.diff(ts)
    v = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * dt)])
    d = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    return TrackError(ts, remove_line(ts, d), "imu", None, int(time_origin_ns))


def combined(first: TrackError, second: TrackError) -> TrackError:
    """The sum of two track errors (the IMU's and autofocus's residual on top of it), on the finer grid."""
    base, other = (first, second) if first.time_s.size >= second.time_s.size else (second, first)
    shift = (other.time_origin_ns - base.time_origin_ns) * 1e-9
    total = base.displacement_m + np.interp(base.time_s, other.time_s + shift, other.displacement_m)
    return TrackError(base.time_s, total, f"{first.method}+{second.method}", second.model or first.model, base.time_origin_ns)
