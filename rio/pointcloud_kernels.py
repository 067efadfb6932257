"""numba kernels of the point clouds' detector (rio.pointcloud.PointCloudDetector), each giving the numbers
of the numpy and scipy code it replaces to the bit (tests/test_pointcloud.py checks them against it).

The odometry makes a point cloud of every scan of every radar; on its 64 x 256 maps and 2 MB cubes numpy's
calls cost more in casts, strided writes and Python set-up than in arithmetic.

- ``ca_cfar_peaks``: the cell-averaging CFAR of ``rio.pointcloud.cfar_2d`` and its local-maximum test in one
  pass (there about twenty numpy calls: two ``scipy.ndimage.uniform_filter`` with their Python set-up, the
  noise, the threshold, the mask, its ``nonzero`` and the 3 x 3 neighbourhood gathers). The box means are
  scipy's running sums (``NI_UniformFilter1D`` of scipy 1.17: a float64 sum of the window, divided by its size
  at each cell; float32 between the two axes, as scipy's output array), the noise and the threshold in float64
  as numpy's promotion of the float32 means by the int64 cell counts makes them, and the detections in
  row-major order as ``np.nonzero`` gives them.
"""

from __future__ import annotations

import numba
import numpy as np

from imaging.numba_target import prefer_full_width_vectors

prefer_full_width_vectors()  # before this module's first numba function (imaging/numba_target.py)


@numba.njit(cache=True)
def _box_mean_doppler(src, size, out, acc):
    """scipy's ``uniform_filter1d(src, size, axis=0, mode="wrap")`` of float32 ``src`` [D, R] into float32
    ``out``; ``acc`` float64 [R] (the running sums of all range columns, advanced row by row)."""
    n_d, n_r = src.shape
    before = size // 2
    after = size - before - 1
    acc[:] = 0.0
    for j in range(size):  # the first window, summed in order from its first cell, as scipy's loop does
        row = (j - before) % n_d
        for k in range(n_r):
            acc[k] += np.float64(src[row, k])
    for k in range(n_r):
        out[0, k] = acc[k] / size
    for i in range(1, n_d):
        enter = (i + after) % n_d
        leave = (i - before - 1) % n_d
        for k in range(n_r):
            acc[k] += np.float64(src[enter, k]) - np.float64(src[leave, k])
            out[i, k] = acc[k] / size


@numba.njit(cache=True)
def _box_mean_range(src, size, out):
    """scipy's ``uniform_filter1d(src, size, axis=1, mode="nearest")`` of float32 ``src`` [D, R] into float32
    ``out``."""
    n_d, n_r = src.shape
    before = size // 2
    after = size - before - 1
    for i in range(n_d):
        acc = 0.0
        for j in range(size):
            acc += np.float64(src[i, min(max(j - before, 0), n_r - 1)])
        out[i, 0] = acc / size
        for k in range(1, n_r):
            acc += np.float64(src[i, min(k + after, n_r - 1)]) - np.float64(src[i, max(k - before - 1, 0)])
            out[i, k] = acc / size


@numba.njit(cache=True)
def ca_cfar_peaks(power, outer, inner, threshold_factor, noise, scratch, mean_outer, mean_inner, acc):
    """Cells of ``power`` float32 [D, R] over the CA-CFAR threshold that are also the largest of their 3 x 3
    neighbourhood (Doppler wraps, range's edge cell is its own neighbour).

    ``outer`` and ``inner`` (Doppler, range) are the box sizes in cells of the training ring and of the
    guard; ``threshold_factor`` the threshold over the noise as a power ratio. Writes the noise estimate
    (float64 [D, R], the training ring's mean) into ``noise``; ``scratch``, ``mean_outer``, ``mean_inner``
    float32 [D, R] and ``acc`` float64 [R] are work buffers. Returns the detections' Doppler and range bins
    (int64 [N] each), in row-major order.
    """
    n_d, n_r = power.shape
    _box_mean_doppler(power, outer[0], scratch, acc)
    _box_mean_range(scratch, outer[1], mean_outer)
    _box_mean_doppler(power, inner[0], scratch, acc)
    _box_mean_range(scratch, inner[1], mean_inner)
    cells_outer = outer[0] * outer[1]
    cells_inner = inner[0] * inner[1]
    ring = np.float64(cells_outer - cells_inner)
    d_bins = np.empty(n_d * n_r, np.int64)
    r_bins = np.empty(n_d * n_r, np.int64)
    found = 0
    for i in range(n_d):
        for k in range(n_r):
            level = (np.float64(mean_outer[i, k]) * cells_outer - np.float64(mean_inner[i, k]) * cells_inner) / ring
            noise[i, k] = level
            peak = power[i, k]
            if not np.float64(peak) > level * threshold_factor:
                continue
            largest = True
            for step_d in range(-1, 2):
                row = (i + step_d) % n_d
                for step_r in range(-1, 2):
                    col = min(max(k + step_r, 0), n_r - 1)
                    if (step_d != 0 or step_r != 0) and not power[row, col] <= peak:
                        largest = False
            if largest:
                d_bins[found] = i
                r_bins[found] = k
                found += 1
    return d_bins[:found], r_bins[:found]

