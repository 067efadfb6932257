"""Plain numpy backprojection: the reference every numba kernel is checked against (and benchmarked)."""

from __future__ import annotations

import numpy as np

C = 299_792_458.0


def backproject_reference(profiles, tx_m, rx_m, grid_m, reference_range_m=None, mode="linear"):
    """Same contract as imaging.backprojection.backproject, one profile at a time, no tricks."""
    grid = np.asarray(grid_m, float).reshape(-1, 3)
    n_p = profiles.data.shape[0]
    r_ref = np.zeros(n_p) if reference_range_m is None else np.asarray(reference_range_m, float)
    image = np.zeros(grid.shape[0], complex)
    axis = profiles.range_axis_m
    for p in range(n_p):
        dr = np.linalg.norm(grid - tx_m[p], axis=1) + np.linalg.norm(grid - rx_m[p], axis=1) - r_ref[p]
        if mode == "exact":
            freqs = profiles.f0_hz + profiles.frequency_step_hz * np.arange(profiles.samples.shape[-1])
            value = np.exp(-2j * np.pi * np.outer(dr, freqs) / C) @ profiles.samples[p].astype(complex)
        else:
            # Outside its axis a profile is zero; linear interpolation runs down to zero over one bin.
            step = profiles.range_step_m
            row = np.concatenate([[0], profiles.data[p].astype(complex), [0]])
            ext = np.concatenate([[axis[0] - step], axis, [axis[-1] + step]])
            if mode == "linear":
                inside = (dr > ext[0]) & (dr < ext[-1])
                value = np.interp(dr, ext, row.real) + 1j * np.interp(dr, ext, row.imag)
            elif mode == "nearest":
                idx = np.round((dr - axis[0]) / step).astype(int)
                inside = (idx >= 0) & (idx < axis.size)
                value = row[1:-1][np.clip(idx, 0, axis.size - 1)]
            else:
                raise ValueError(mode)
            value = np.where(inside, value, 0.0) * np.exp(-2j * np.pi * profiles.carrier_hz * dr / C)
        image += value
    return image.reshape(np.shape(grid_m)[:-1])
