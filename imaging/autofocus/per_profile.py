"""A non-parametric track error: one free value per slow-time group, refined to the sharpest image, and
the combination of a low-order model (the smooth part) with it (the rest).

PGA's phase gradient (``imaging.autofocus.pga``) gives one value per group but, on its own, leaves most of a
pulse-to-pulse random walk in place: each scatterer's phase history is read through a window that still
holds the clutter the blur spread into it. Starting from it, the displacements of all groups are refined
together to a maximum of the image's sharpness ``sum |I|^4`` (``per_group_sharpening``), with no model:
every group's value is a free parameter. In the "combined" method the smooth part is the entropy model's
(``imaging.autofocus.track_model``): it starts the refinement, and the result carries the model and the
spectrum of what the per-group values add to it (the residual), so a reader sees how much of the track
error no low-order model holds and at which frequencies. See docs/signal-model.md.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from imaging.autofocus.pga import phase_gradient_autofocus
from imaging.autofocus.subapertures import TILE, GroupImages
from imaging.autofocus.track_model import entropy_estimate
from imaging.core.track_error import remove_line

if TYPE_CHECKING:
    from imaging.autofocus.options import AutofocusOptions

log = logging.getLogger("sarbot.imaging.autofocus")

#: Bands the residual's spectrum is reported in (log-spaced from one cycle over the span to the groups'
#: Nyquist rate).
SPECTRUM_BANDS = 12


def per_group_sharpening(g: GroupImages, start_m: np.ndarray, iterations: int, tolerance_rad: float = 1e-4
                         ) -> tuple[np.ndarray, int]:
    """Every group's displacement refined from ``start_m`` [Q] to a maximum of the image's sharpness
    ``sum |I|^4``, no model. Returns (displacement [Q] m less its line, iterations).

    With ``C_q = exp(j phi_q) B_q`` group q's part of the image ``I``, the phase that maximises
    ``sum_g w_g |I_g|^2`` for fixed weights ``w = |I|^2`` turns ``C_q`` towards the rest of the image:
    ``phi_q += arg sum_g w_g conj(C_qg) I_g``. All groups are updated at once and the weights recomputed
    (a fixed point of the sharpness, one product of the group images with a vector per iteration), until
    the rms update is below ``tolerance_rad``. The sum is a weighted PGA over every pixel at once, the
    current image its own window; it needs no entropy difference to resolve, which float32 group images
    cannot give for one pulse in hundreds.
    """
    delta = np.asarray(start_m, float).copy()
    mask = g.weight.reshape(-1, TILE)
    c_mean = g.c.mean(axis=1)
    it = 0
    for it in range(1, iterations + 1):
        e = np.exp(1j * g.phase(delta)).astype(np.complex64)  # [Q, T]
        img = np.matmul(e.T[:, None, :], g.b)[:, 0, :] * mask  # [T, TILE]
        v = ((np.abs(img) ** 2) * img).astype(np.complex64)
        z = (np.conj(e.T) * np.matmul(np.conj(g.b), v[:, :, None])[:, :, 0]).sum(axis=0)  # [Q]
        eps = np.angle(z)
        delta += eps / (2.0 * g.k * c_mean)
        if np.sqrt(np.mean(eps ** 2)) < tolerance_rad:
            break
    return remove_line(g.time_s, delta), it


def residual_spectrum(time_s: np.ndarray, residual_m: np.ndarray, bands: int = SPECTRUM_BANDS) -> dict:
    """The power of a residual track error in log-spaced frequency bands (Hann-windowed periodogram on the
    group times taken as uniform): band edges in Hz and the rms in metres each band holds."""
    t = np.asarray(time_s, float)
    r = remove_line(t, np.asarray(residual_m, float))
    n = t.size
    dt = float(np.ptp(t)) / max(n - 1, 1)
    window = np.hanning(n)
    spec = np.abs(np.fft.rfft(r * window)) ** 2
    freq = np.fft.rfftfreq(n, dt if dt > 0 else 1.0)
    # Parseval with the window's power: band powers add up to the residual's mean square.
    power = spec * 2.0 / (n * np.sum(window ** 2))
    lo, hi = max(freq[1], 1e-12) if n > 2 else 1.0, max(freq[-1], 2e-12)
    edges = np.geomspace(lo, hi * (1 + 1e-9), bands + 1)
    rms = [float(np.sqrt(power[(freq >= a) & (freq < b)].sum())) for a, b in zip(edges[:-1], edges[1:])]
    return {"band_edges_hz": edges.tolist(), "band_rms_m": rms, "rms_m": float(np.sqrt(np.mean(r ** 2)))}


def per_profile_estimate(g: GroupImages, options: AutofocusOptions) -> tuple[np.ndarray, dict, int]:
    """The "per-profile" method: PGA's values refined group by group to the sharpest image. The model holds
    the spectrum of the whole estimate (there is no smooth part)."""
    start, it = phase_gradient_autofocus(g, options)
    delta, it_np = per_group_sharpening(g, start, options.per_profile_iterations)
    return delta, {"kind": "per-profile", "smooth": None, "residual_spectrum": residual_spectrum(g.time_s, delta)}, it + it_np


def combined_estimate(g: GroupImages, options: AutofocusOptions) -> tuple[np.ndarray, dict, int]:
    """The "combined" method: the entropy model for the smooth part, then every group refined from it to the
    sharpest image for the rest. The model holds the smooth model (None where the entropy method kept
    PGA's values) and the spectrum of the residual (the estimate less the smooth part). Where the entropy
    method keeps PGA's values (its model did not beat them), the result is "per-profile"'s: so on Gotcha
    with a random walk (docs/results/autofocus_per_profile.json)."""
    smooth, model, it = entropy_estimate(g, options)
    delta, it_np = per_group_sharpening(g, smooth, options.per_profile_iterations)
    spectrum = residual_spectrum(g.time_s, delta - smooth)
    log.info("autofocus (combined): per-group residual over the smooth part %.3g m rms", spectrum["rms_m"])
    return delta, {"kind": "combined", "smooth": model, "residual_spectrum": spectrum}, it + it_np
