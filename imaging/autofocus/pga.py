"""Phase gradient autofocus carried over to backprojection: one track-error value per slow-time group.

The brightest distinct peaks are the centred scatterers; a scatterer's "phase history" is its windowed
image taken back to slow time by the adjoint of the exact near-field group response (as the inverse FFT
is in the polar-format original); the phase gradient ``arg sum_s h_s[q] conj(h_s[q-1])`` is integrated, its
linear part dropped, and the window follows the blur that is left (its -10 dB extent). Non-parametric.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from imaging.autofocus.subapertures import TILE, GroupImages, resolution_m
from imaging.core.track_error import remove_line

if TYPE_CHECKING:
    from imaging.autofocus.options import AutofocusOptions


def _distinct_peaks(img: np.ndarray, points_m: np.ndarray, n: int, separation_m: float) -> list[tuple[int, int]]:
    """(tile, pixel) of up to n tile peaks, brightest first, at least ``separation_m`` apart and within 30 dB
    of the brightest (fainter ones are noise)."""
    peak = np.argmax(np.abs(img), axis=1)
    power = np.abs(img[np.arange(img.shape[0]), peak]) ** 2
    chosen: list[tuple[int, int]] = []
    for t in np.argsort(power)[::-1]:
        if power[t] < 1e-3 * power.max() or power[t] == 0:
            break
        p = points_m[t, peak[t]]
        if all(np.linalg.norm(p - points_m[u, v]) >= separation_m for u, v in chosen):
            chosen.append((int(t), int(peak[t])))
            if len(chosen) == n:
                break
    return chosen


def phase_gradient_autofocus(g: GroupImages, options: AutofocusOptions) -> tuple[np.ndarray, int]:
    """Displacement per group [Q] by PGA over the group images, and the iterations it took.

    Up to ``options.scatterers`` bright, distinct peaks are the centred scatterers. A scatterer's phase
    history is its windowed image taken back to slow time by the adjoint of the ideal group response
    (the inverse FFT of polar-format PGA, here with exact near-field ranges):
    ``h[q] = sum_{g in W} I_g exp(+j 2 k (|g - a_q| - |g_peak - a_q|))`` with a_q group q's antenna phase
    centre. The window spans half a range resolution cell either side of the peak's range and, in
    cross-range, 1.5 times the extent above -10 dB of the centred peak (the blur still to be undone),
    never wider than the iteration before nor narrower than two resolution cells. The phase gradient is the
    energy-weighted sum over the scatterers of ``h[q] conj(h[q-1])``, integrated, its linear part dropped.
    """
    delta = np.zeros(g.b.shape[1])
    c_mean = g.c.mean(axis=1)
    n_t = g.b.shape[0]
    pts = g.points_m.reshape(n_t, TILE, 3)
    valid = g.weight.reshape(n_t, TILE) > 0
    centre = pts[valid].mean(axis=0)
    look = centre - g.antenna_centre_m
    look /= np.linalg.norm(look)
    extent = float(np.max(np.ptp(pts[valid], axis=0)))
    floor = 2.0 * resolution_m(g)
    window = max(0.5 * extent, floor)
    half_line = 0.5 * g.range_resolution_m if g.range_resolution_m else floor
    usable = g.points_m[g.weight > 0]
    usable_index = np.flatnonzero(g.weight > 0)
    it = 0
    for it in range(1, options.pga_iterations + 1):
        phase = g.phase(delta)
        img = np.where(valid, g.image(phase), 0)
        flat = img.ravel()
        peaks = _distinct_peaks(img, pts, options.scatterers, 2.0 * window)  # windows that do not overlap
        if not peaks:
            break
        h = np.zeros((g.b.shape[1], len(peaks)), np.complex128)
        spread = 0.0
        for j, (t, i) in enumerate(peaks):
            gp = pts[t, i]
            d = usable - gp
            along = d @ look
            cross = np.linalg.norm(d - along[:, None] * look, axis=1)
            line = np.abs(along) <= half_line
            # The window: where the centred line's intensity stays above -10 dB of its peak (the blur's
            # extent, as in the original), never wider than last time.
            level = np.abs(flat[usable_index[line]]) ** 2
            above = cross[line][level >= 0.1 * level.max()]
            spread = max(spread, float(above.max()) if above.size else 0.0)
            near = line & (cross <= window)
            r_peak = np.linalg.norm(gp - g.group_antenna_m, axis=1)  # [Q]
            r = np.linalg.norm(usable[near][None, :, :] - g.group_antenna_m[:, None, :], axis=2)  # [Q, W]
            h[:, j] = np.exp(2j * g.k * (r - r_peak[:, None])) @ flat[usable_index[near]]
        grad = np.angle(np.sum(h[1:] * np.conj(h[:-1]), axis=1))
        eps = np.concatenate([[0.0], np.cumsum(grad)])
        weight = (np.abs(h) ** 2).sum(axis=1)
        eps = remove_line(g.time_s, eps, weight)
        delta = delta - eps / (2.0 * g.k * c_mean)
        window = min(window, max(1.5 * spread, floor))
        if np.sqrt(np.average(eps ** 2, weights=weight)) < options.pga_tolerance_rad:
            break
    return remove_line(g.time_s, delta), it



def pga_estimate(g: GroupImages, options: AutofocusOptions) -> tuple[np.ndarray, None, int]:
    """The "pga" method: PGA's displacement per group, no model, and the iterations it took."""
    delta, iterations = phase_gradient_autofocus(g, options)
    return delta, None, iterations
