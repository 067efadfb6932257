"""Autofocus for backprojected images: the antenna-track error along a known direction, estimated from the data.

A track error the trajectory does not know (vibration along the boresight, odometry drift) displaces the
antennas by delta(t) along a direction u. Profile p then reaches pixel g over a two-way range shorter by
``2 delta_p c_pg`` with ``c_pg = u_p . (g - a_p) / |g - a_p|``, so backprojection on the assumed track
leaves each profile's contribution with a phase error ``-2 k c_pg delta_p`` (k = 2 pi / wavelength at the
carrier). For millimetre errors against centimetre range cells the envelope does not move; the phase is
all that matters, and it is all the estimate needs.

The estimate works on sub-aperture images: profiles are put in ``Q`` slow-time groups short enough that
delta is constant within one, and each group is backprojected by the ordinary kernel onto a set of pixels
(the whole image when small, else patches around its strongest scatterers). With ``B[q, g]`` the group
images, the image for a track error delta is

    I_g(delta) = sum_q exp(j 2 k c_qg delta_q) B[q, g]

where ``c`` is evaluated per 16 x 16 pixel tile (its angle varies by well under a degree across one). Two
estimators:

``pga``      phase gradient autofocus carried over to backprojection. The brightest distinct peaks are the
             centred scatterers; a scatterer's "phase history" is its windowed image taken back to slow time
             by the adjoint of the exact near-field group response (as the inverse FFT is in the
             polar-format original); the phase gradient ``arg sum_s h_s[q] conj(h_s[q-1])`` is integrated,
             its linear part dropped, and the window follows the blur that is left (its -10 dB extent).
             Non-parametric: one value per group.
``entropy``  minimum image entropy over a low-order model of the track error: Legendre polynomials of
             order 2 and up (orders 0 and 1 only move the image) plus sinusoids whose frequencies are free
             parameters, started from a PGA estimate. The gradient is exact and costs one product of the
             group images with a vector, ``dE/dphi_qg = 2 Im(exp(j phi) sum_g B[q, g] D_g)`` with
             ``D = (ln p + E) conj(I) / S``, not a finite difference over images.

The track error is defined only up to a constant and a linear drift: those move the image, they do not blur
it. A result that does not lower the image's entropy is not applied (``AutofocusResult.applied``): a scene
with nothing to focus on is never made worse.

``fit_vibration`` reads frequency, amplitude and phase of a vibration off an estimated track error by a
sinusoid fit (with the unobservable offset and drift as nuisance terms), so the vibration no longer has to
be inferred from the level of its paired side lobes.

Autofocus needs something to focus on: an image (noise, diffuse clutter) whose brightest pixel stands less
than ``min_contrast_db`` above its background is left as it is. The background is the median intensity of
noise estimated from the dimmest tenth of the pixels; noise alone reaches 13 dB above it at a million
pixels, a point target tens of dB.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Iterable

import numpy as np
import scipy.optimize

from imaging.backprojection import backproject, patch_order
from imaging.core.config import require
from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.geometry import principal_axis
from imaging.range_compression import RangeProfiles  # noqa: F401 (ProfileBlock's type)

log = logging.getLogger(f"sarbot.{__name__}")

METHODS = ("none", "pga", "entropy")
TILE = 256  # pixels of one tile (16 x 16 in patch order) that share one geometry factor per group
#: The entropy model's estimate is kept over PGA's only if the brightest pixel keeps at least this part of
#: its power under it (-0.5 dB). Undoing a real track error gathers a scatterer's energy back into its peak;
#: a model that lowers the peak while lowering the entropy has moved energy out of the estimation pixels.
MODEL_PEAK_KEEP = 10 ** -0.05


@dataclasses.dataclass
class AutofocusOptions:
    """How to estimate the track error.

    ``groups``: slow-time groups (the resolution of the estimate in time); ``max_pixels``: the whole image
    is used up to this many pixels, else ``scatterers`` patches of ``patch_px`` x ``patch_px`` around the
    strongest; ``poly_order`` and ``sinusoids``: the entropy model (the polynomial order is chosen up to
    ``poly_order`` by the Bayesian information criterion on the PGA estimate: no more than the scene needs).
    """

    method: str = "entropy"
    groups: int = 256
    max_pixels: int = 65536
    scatterers: int = 16
    patch_px: int = 64
    pga_iterations: int = 8
    pga_tolerance_rad: float = 0.01
    poly_order: int = 6
    sinusoids: int = 1
    entropy_iterations: int = 200
    min_contrast_db: float = 20.0  # brightest pixel over the background (noise median): below it, nothing to focus on

    def __post_init__(self) -> None:
        require(self.method in METHODS, "method", f"must be one of {', '.join(METHODS)}, got {self.method!r}")
        require(4 <= self.groups <= 4096, "groups", f"must be 4 to 4096, got {self.groups}")
        require(self.max_pixels >= TILE, "max_pixels", f"must be at least {TILE}, got {self.max_pixels}")
        require(1 <= self.scatterers <= 256, "scatterers", f"must be 1 to 256, got {self.scatterers}")
        require(16 <= self.patch_px <= 256 and self.patch_px % 16 == 0, "patch_px",
                f"must be a multiple of 16 from 16 to 256, got {self.patch_px}")
        require(1 <= self.pga_iterations <= 100, "pga_iterations", f"must be 1 to 100, got {self.pga_iterations}")
        require(1 <= self.poly_order <= 8, "poly_order", f"must be 1 to 8, got {self.poly_order}")
        require(0 <= self.sinusoids <= 4, "sinusoids", f"must be 0 to 4, got {self.sinusoids}")
        require(math.isfinite(self.min_contrast_db), "min_contrast_db", f"must be finite, got {self.min_contrast_db}")


@dataclasses.dataclass
class ProfileBlock:
    """Range profiles and what autofocus needs of each: antennas [P, 3], slow time [P] in seconds (from any
    origin), the unit direction [P, 3] the track error displaces the antennas along, reference ranges."""

    profiles: RangeProfiles
    tx_m: np.ndarray
    rx_m: np.ndarray
    time_s: np.ndarray
    direction: np.ndarray
    reference_range_m: np.ndarray | None = None


@dataclasses.dataclass
class TrackError:
    """Displacement of the antennas along the block's direction against the trajectory, over slow time.

    ``time_s`` [Q] group centres (seconds from ``time_origin_ns`` where the profiles came from a recording),
    ``displacement_m`` [Q]. Constant and linear parts are arbitrary (they only move the image); they are
    set to zero over the aperture. ``model`` holds the fitted terms where the estimate is parametric.
    """

    time_s: np.ndarray
    displacement_m: np.ndarray
    method: str
    model: dict | None = None
    time_origin_ns: int = 0

    def at(self, time_s: np.ndarray) -> np.ndarray:
        """The displacement at any time (linear between group centres, held beyond them). The model, where
        there is one, is not used here: its offset and drift are arbitrary and would move the image."""
        return np.interp(np.asarray(time_s, float), self.time_s, self.displacement_m)

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(self.displacement_m ** 2)))

    @classmethod
    def of_vibration(cls, vibration, time_s: np.ndarray, vibration_t0_ns: int, time_origin_ns: int) -> "TrackError":
        """A known vibration (``imaging.core.geometry.Vibration``, phase referred to ``vibration_t0_ns``) as a
        track error at ``time_s`` from ``time_origin_ns``: what a perfect estimate would give."""
        t = np.asarray(time_s, float)
        return cls(t, vibration.displacement_m(t + (time_origin_ns - vibration_t0_ns) * 1e-9), "truth", None, int(time_origin_ns))


@dataclasses.dataclass
class AutofocusResult:
    """The estimate, and the entropy of the estimation pixels before and after (nats)."""

    track_error: TrackError
    entropy_before: float
    entropy_after: float
    applied: bool
    pixels: int
    groups: int
    iterations: int
    note: str = ""


# -- the group images ------------------------------------------------------------------------------------
@dataclasses.dataclass
class GroupImages:
    """B [T, Q, TILE] complex64 (tile, group, pixel in tile), the geometry factor c [Q, T], group times [Q],
    pixel positions [T * TILE, 3] (padding pixels: weight 0), the carrier wavenumber k (rad/m)."""

    b: np.ndarray
    c: np.ndarray
    time_s: np.ndarray
    points_m: np.ndarray
    weight: np.ndarray
    k: float
    aperture_m: float
    antenna_centre_m: np.ndarray
    group_antenna_m: np.ndarray  # [Q, 3] mean antenna phase centre of each group
    range_resolution_m: float  # c / (2 B); one range line of the PGA window

    def image(self, phase: np.ndarray) -> np.ndarray:
        """I [T, TILE] for phases [Q, T]."""
        e = np.exp(1j * phase).astype(np.complex64).T  # [T, Q]
        return np.matmul(e[:, None, :], self.b)[:, 0, :]

    def phase(self, displacement_m: np.ndarray) -> np.ndarray:
        return 2.0 * self.k * self.c * displacement_m[:, None]


def _tiles(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points padded to whole tiles (the last point repeated, weight 0)."""
    n = points_m.shape[0]
    pad = (-n) % TILE
    weight = np.concatenate([np.ones(n, np.float32), np.zeros(pad, np.float32)])
    return np.concatenate([points_m, np.repeat(points_m[-1:], pad, axis=0)]), weight


def group_images(blocks: Iterable[ProfileBlock], points_m: np.ndarray, n_groups: int, t_range_s: tuple[float, float]) -> GroupImages:
    """Backproject every slow-time group onto ``points_m`` [G, 3] (in tile order: 256 consecutive points
    close together), one kernel call per (block, group)."""
    pts, weight = _tiles(np.ascontiguousarray(points_m, np.float64))
    edges = np.linspace(t_range_s[0], t_range_s[1], n_groups + 1)
    edges[-1] = np.nextafter(edges[-1], np.inf)
    b = np.zeros((n_groups, pts.shape[0]), np.complex64)
    count = np.zeros(n_groups)
    t_sum = np.zeros(n_groups)
    a_sum = np.zeros((n_groups, 3))
    u_sum = np.zeros((n_groups, 3))
    tmp = np.zeros(pts.shape[0], np.complex128)
    k = None
    bandwidth = None
    for blk in blocks:
        prof = blk.profiles
        bandwidth = prof.bandwidth_hz
        k = 2.0 * math.pi * prof.carrier_hz / SPEED_OF_LIGHT_MPS
        q_of = np.searchsorted(edges, blk.time_s, side="right") - 1
        inside = (q_of >= 0) & (q_of < n_groups)
        # Profiles come in time order, so a group is a run of consecutive profiles.
        change = np.flatnonzero(np.diff(q_of)) + 1
        starts = np.concatenate([[0], change])
        stops = np.concatenate([change, [q_of.size]])
        for a, z in zip(starts, stops):
            q = int(q_of[a])
            if not inside[a]:
                continue
            sub = dataclasses.replace(prof, data=prof.data[a:z], samples=None if prof.samples is None else prof.samples[a:z],
                                      rows=None if prof.rows is None else prof.rows[a:z])
            tmp[:] = 0
            ref = None if blk.reference_range_m is None else blk.reference_range_m[a:z]
            backproject(sub, blk.tx_m[a:z], blk.rx_m[a:z], pts, reference_range_m=ref, out=tmp)
            b[q] += tmp.astype(np.complex64)
            count[q] += z - a
            t_sum[q] += blk.time_s[a:z].sum()
            a_sum[q] += (0.5 * (blk.tx_m[a:z] + blk.rx_m[a:z])).sum(axis=0)
            u_sum[q] += blk.direction[a:z].sum(axis=0)
    keep = count > 0
    if keep.sum() < 4 or k is None:
        raise ValueError(f"autofocus needs profiles spread over time; {int(keep.sum())} of {n_groups} groups hold any")
    return assemble_group_images(b[keep], t_sum[keep] / count[keep], a_sum[keep] / count[keep, None], u_sum[keep], pts,
                                 weight, k, SPEED_OF_LIGHT_MPS / (2.0 * abs(bandwidth)) if bandwidth else 0.0)


def assemble_group_images(b: np.ndarray, time_s: np.ndarray, antenna_m: np.ndarray, direction: np.ndarray,
                          points_m: np.ndarray, weight: np.ndarray, k: float, range_resolution_m: float) -> GroupImages:
    """GroupImages from group images ``b`` [Q, G] on ``points_m`` [G, 3] (whole tiles in tile order, G a
    multiple of TILE; ``weight`` 0 for padding), the groups' times [Q], antenna phase centres [Q, 3] and
    track-error directions [Q, 3] (any length)."""
    n_t = points_m.shape[0] // TILE
    u = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    centres = points_m.reshape(n_t, TILE, 3).mean(axis=1)  # [T, 3]
    los = centres[None, :, :] - antenna_m[:, None, :]
    c = np.einsum("qk,qtk->qt", u, los) / np.linalg.norm(los, axis=2)
    bt = np.ascontiguousarray(b.reshape(b.shape[0], n_t, TILE).transpose(1, 0, 2))
    extent = antenna_m - antenna_m.mean(axis=0)
    length_m = float(np.ptp(extent @ principal_axis(extent)))
    return GroupImages(bt, c, np.asarray(time_s, float), points_m, weight, k, length_m,
                       antenna_m.mean(axis=0), antenna_m, range_resolution_m)


# -- image sharpness -------------------------------------------------------------------------------------
def image_entropy(image: np.ndarray) -> float:
    """Shannon entropy (nats) of an image's normalised intensity; lower is sharper."""
    w = np.abs(np.asarray(image)) ** 2
    s = w.sum()
    if s <= 0:
        return 0.0
    p = w.ravel() / s
    p = p[p > 0]
    return float(-(p * np.log(p)).sum())


def _entropy_and_gradient(g: GroupImages, phase: np.ndarray) -> tuple[float, np.ndarray]:
    """Entropy of the group images' sum under ``phase`` [Q, T] and its gradient dE/dphase [Q, T]."""
    e = np.exp(1j * phase).astype(np.complex64)
    img = np.matmul(e.T[:, None, :], g.b)[:, 0, :] * g.weight.reshape(-1, TILE)
    w = (img.real.astype(np.float64) ** 2 + img.imag.astype(np.float64) ** 2)
    s = w.sum()
    p = w / s
    logp = np.log(np.maximum(p, 1e-300))
    ent = float(-(p * logp).sum())
    d = ((logp + ent) / s * np.conj(img)).astype(np.complex64)  # [T, TILE]
    bd = np.matmul(g.b, d[:, :, None])[:, :, 0]  # [T, Q]
    grad = 2.0 * np.imag(e * bd.T)
    return ent, grad


# -- PGA -------------------------------------------------------------------------------------------------
def remove_line(t: np.ndarray, v: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """v less its (weighted) least-squares line over t: a track error as an image can see it (an offset and
    a drift only move the image)."""
    a = np.column_stack([np.ones_like(t), t - t.mean()])
    sw = np.ones_like(t) if w is None else np.sqrt(w)
    coef, *_ = np.linalg.lstsq(a * sw[:, None], v * sw, rcond=None)
    return v - a @ coef


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


# -- the low-order model ---------------------------------------------------------------------------------
def _legendre(tau: np.ndarray, order: int) -> np.ndarray:
    """Columns P2..P_order of tau in [-1, 1] (P0 and P1 only move the image)."""
    cols = [np.polynomial.legendre.Legendre.basis(n)(tau) for n in range(2, order + 1)]
    return np.column_stack(cols) if cols else np.zeros((tau.size, 0))


def evaluate_model(model: dict, time_s: np.ndarray) -> np.ndarray:
    """The displacement of a fitted ``legendre+sinusoids`` model at ``time_s``."""
    t0, half = model["t_centre_s"], model["t_half_s"]
    tau = np.clip((time_s - t0) / half, -1.0, 1.0)
    out = _legendre(tau, model["poly_order"]) @ np.asarray(model["poly_m"], float) if model["poly_order"] >= 2 else np.zeros_like(tau)
    for f, a, b in model["sinusoids"]:
        w = 2 * math.pi * f * (time_s - t0)
        out = out + a * np.cos(w) + b * np.sin(w)
    return out


def _fit_sinusoids(t, v, poly_order: int, n_sin: int, weight=None):
    """Least-squares fit v ~ line + P2..P_order + n_sin sinusoids (frequencies found one by one from the
    residual's zero-padded periodogram, then refined together; none below one cycle over the span).
    Returns (t_centre_s, t_half_s, coefficients [line, P2.., cos, sin per sinusoid], frequencies, residual
    rms)."""
    t0 = 0.5 * (t.min() + t.max())
    half = max(0.5 * np.ptp(t), 1e-12)
    tau = (t - t0) / half
    sw = np.ones_like(t) if weight is None else np.sqrt(weight / weight.mean())
    fixed = np.column_stack([np.ones_like(tau), tau, _legendre(tau, poly_order)])
    freqs: list[float] = []

    def design(fs):
        cols = [fixed]
        for f in fs:
            w = 2 * math.pi * f * (t - t0)
            cols.append(np.column_stack([np.cos(w), np.sin(w)]))
        return np.column_stack(cols)

    def solve(fs):
        a = design(fs)
        coef, *_ = np.linalg.lstsq(a * sw[:, None], v * sw, rcond=None)
        return coef, v - a @ coef

    dt = np.median(np.diff(np.sort(t))) if t.size > 1 else 1.0
    for _ in range(n_sin):
        _, r = solve(freqs)
        n_fft = 1 << int(np.ceil(np.log2(64 * t.size)))
        # The residual on a uniform grid (group times are near uniform).
        tu = np.linspace(t.min(), t.max(), t.size)
        spec = np.abs(np.fft.rfft(np.interp(tu, t, r) * np.hanning(t.size), n_fft))
        fgrid = np.fft.rfftfreq(n_fft, (tu[1] - tu[0]) if t.size > 1 else dt)
        # Below one cycle over the aperture a sinusoid is a bend: the polynomial has it.
        spec[fgrid < 1.0 / np.ptp(t)] = 0
        if not spec.any():
            break
        freqs.append(float(fgrid[np.argmax(spec)]))
    if freqs:
        def resid(fs):
            return solve(fs)[1] * sw
        lo, hi = 1.0 / np.ptp(t), 0.5 / dt
        sol = scipy.optimize.least_squares(resid, np.clip(freqs, lo * 1.0001, hi * 0.9999), bounds=(lo, hi),
                                           x_scale=np.maximum(np.array(freqs), 1e-9) * 0.05)
        freqs = [float(f) for f in sol.x]
    coef, r = solve(freqs)
    return t0, half, coef, freqs, float(np.sqrt(np.mean(r ** 2)))


def fit_track_model(time_s: np.ndarray, displacement_m: np.ndarray, max_poly_order: int, sinusoids: int,
                    weight: np.ndarray | None = None) -> dict:
    """The ``legendre+sinusoids`` model fitted to an estimated track error, its polynomial order chosen by
    the Bayesian information criterion (no more terms than the data support). Offset and drift are fitted
    and left out of the model."""
    t, v = np.asarray(time_s, float), np.asarray(displacement_m, float)
    best = None
    for order in range(1, max_poly_order + 1):
        t0, half, coef, freqs, rms = _fit_sinusoids(t, v, order, sinusoids, weight)
        k = 2 + max(order - 1, 0) + 3 * len(freqs)
        bic = t.size * math.log(max(rms, 1e-15) ** 2) + k * math.log(t.size)
        if best is None or bic < best[0] - 1e-9:
            best = (bic, order, t0, half, coef, freqs)
    _, order, t0, half, coef, freqs = best
    n_poly = max(order - 1, 0)
    return {"kind": "legendre+sinusoids", "t_centre_s": t0, "t_half_s": half, "poly_order": order,
            "poly_m": coef[2:2 + n_poly].tolist(),
            "sinusoids": [[f, float(coef[2 + n_poly + 2 * i]), float(coef[3 + n_poly + 2 * i])] for i, f in enumerate(freqs)]}


def _model_design(g: GroupImages, model: dict):
    """The model's parameter vector, and a function giving (displacement [Q], d displacement / d params
    [Q, n]) for a parameter vector. Parameters: polynomial and sinusoid coefficients in units of
    1 / (2 k) metres (radians of two-way phase), frequencies in Hz."""
    t = g.time_s
    t0, half, order = model["t_centre_s"], model["t_half_s"], model["poly_order"]
    poly = _legendre(np.clip((t - t0) / half, -1, 1), order)
    n_poly = poly.shape[1]
    scale = 1.0 / (2.0 * g.k)
    x0 = [p / scale for p in model["poly_m"]]
    for f, a, b in model["sinusoids"]:
        x0 += [a / scale, b / scale, f]

    def evaluate(x):
        d = poly @ x[:n_poly] * scale
        jac = [poly * scale]
        for i in range(len(model["sinusoids"])):
            a, b, f = x[n_poly + 3 * i: n_poly + 3 * i + 3]
            w = 2 * math.pi * (t - t0)
            cw, sn = np.cos(f * w), np.sin(f * w)
            d = d + (a * cw + b * sn) * scale
            jac.append(np.column_stack([cw * scale, sn * scale, (-a * sn + b * cw) * w * scale]))
        return d, np.column_stack(jac)

    def to_model(x):
        out = dict(model)
        out["poly_m"] = (np.asarray(x[:n_poly]) * scale).tolist()
        out["sinusoids"] = [[float(x[n_poly + 3 * i + 2]), float(x[n_poly + 3 * i] * scale), float(x[n_poly + 3 * i + 1] * scale)]
                            for i in range(len(model["sinusoids"]))]
        return out

    return np.asarray(x0, float), evaluate, to_model


def minimum_entropy(g: GroupImages, model: dict, iterations: int) -> tuple[dict, float, int]:
    """Refine the model's parameters by minimising the entropy of the group images' sum (L-BFGS, exact
    gradient through the group images). Returns (model, entropy, iterations)."""
    x0, evaluate, to_model = _model_design(g, model)
    if x0.size == 0:
        return model, _entropy_and_gradient(g, np.zeros_like(g.c))[0], 0

    def fun(x):
        d, jac = evaluate(x)
        ent, grad_phase = _entropy_and_gradient(g, g.phase(d))
        grad_d = (grad_phase * 2.0 * g.k * g.c).sum(axis=1)
        return ent, jac.T @ grad_d

    # Frequencies stay within one cycle over the aperture and the groups' Nyquist rate; amplitudes are free.
    span = float(np.ptp(g.time_s))
    nyquist = 0.5 / float(np.median(np.diff(g.time_s)))
    n_poly = x0.size - 3 * len(model["sinusoids"])
    bounds = [(None, None)] * n_poly
    for _ in model["sinusoids"]:
        bounds += [(None, None), (None, None), (1.0 / span, nyquist)]
    # Entropy to a part in a million (a few micro-nats): finer steps change no image measurably.
    res = scipy.optimize.minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                                  options={"maxiter": iterations, "ftol": 1e-6})
    return to_model(res.x), float(res.fun), int(res.nit)


# -- putting it together ---------------------------------------------------------------------------------
def select_pixels(image: np.ndarray, points_m: np.ndarray, options: AutofocusOptions) -> np.ndarray:
    """The pixels to estimate on, in tile order [G, 3]: the whole image up to ``max_pixels``, else
    ``scatterers`` patches around the brightest pixels (non-overlapping)."""
    shape = image.shape
    if image.size <= options.max_pixels or image.ndim < 2:
        order = patch_order(shape)
        flat = points_m.reshape(-1, 3)
        return flat if order is None else flat[order]
    ny, nx = shape[-2], shape[-1]
    plane = np.abs(image.reshape(-1, ny, nx)).max(axis=0)
    pts = points_m.reshape(-1, ny, nx, 3)
    best_layer = np.abs(image.reshape(-1, ny, nx)).reshape(-1, ny * nx).argmax(axis=0).reshape(ny, nx)
    half = options.patch_px // 2
    taken = np.zeros((ny, nx), bool)
    out = []
    for flat_i in np.argsort(plane.ravel())[::-1]:
        iy, ix = divmod(int(flat_i), nx)
        y0 = min(max(iy - half, 0), max(ny - options.patch_px, 0))
        x0 = min(max(ix - half, 0), max(nx - options.patch_px, 0))
        sl = (slice(y0, y0 + options.patch_px), slice(x0, x0 + options.patch_px))
        if taken[sl].any():
            continue
        taken[sl] = True
        patch = pts[best_layer[iy, ix]][sl]
        order = patch_order(patch.shape[:2])
        flat = patch.reshape(-1, 3)
        out.append(flat if order is None else flat[order])
        if len(out) == options.scatterers:
            break
    return np.concatenate(out)


def resolution_m(g: GroupImages) -> float:
    """Cross-range resolution lambda r / (2 La) at the estimation pixels' centre."""
    centre = g.points_m[g.weight > 0].mean(axis=0)
    r = float(np.linalg.norm(centre - g.antenna_centre_m))
    return (math.pi / g.k) * r / (2.0 * max(g.aperture_m, 1e-9))


def estimate_track_error(blocks: Callable[[], Iterable[ProfileBlock]], image: np.ndarray, points_m: np.ndarray,
                         options: AutofocusOptions | None = None, time_range_s: tuple[float, float] | None = None
                         ) -> AutofocusResult:
    """Estimate the track error of an image formed from ``blocks`` (called again for a second pass).

    Parameters
    ----------
    blocks : callable
        Returns an iterable of ProfileBlock, the profiles the image was formed from, in time order.
    image : ndarray, complex, shape (...)
        The image formed on the assumed track.
    points_m : ndarray, shape image.shape + (3,)
        Its pixels' world positions.
    time_range_s : (first, last), optional
        The profiles' time span, where the caller knows it (else one more pass over the blocks finds it).
    """
    options = options or AutofocusOptions()
    note = nothing_to_focus_on(image, options)
    if note:
        e = image_entropy(image)
        return AutofocusResult(TrackError(np.zeros(2), np.zeros(2), options.method), e, e, False, 0, 0, 0, note)
    pixels = select_pixels(image, points_m, options)
    t_lo, t_hi = time_range_s if time_range_s is not None else (np.inf, -np.inf)
    for blk in blocks() if time_range_s is None else ():
        if blk.time_s.size:
            t_lo, t_hi = min(t_lo, float(blk.time_s.min())), max(t_hi, float(blk.time_s.max()))
    if not np.isfinite(t_lo) or t_hi <= t_lo:
        raise ValueError("autofocus needs profiles spread over time")
    return estimate_on_group_images(group_images(blocks(), pixels, options.groups, (t_lo, t_hi)), options)


def nothing_to_focus_on(image: np.ndarray, options: AutofocusOptions) -> str:
    """Why an image has nothing to focus on (its brightest pixel too little above the background), or ""."""
    power = np.abs(image) ** 2
    power = power[power > 0]  # pixels nothing was integrated into (a strip-map tile's edges) are no background
    if power.size == 0:
        return "nothing to focus on: the image is empty"
    # The noise's median from the dimmest tenth (exponential intensity: median = p10 ln 2 / -ln 0.9), so
    # that a target filling much of a small image does not count as background.
    floor = np.percentile(power, 10) * (math.log(2) / -math.log(0.9))
    contrast_db = 10 * math.log10(power.max() / floor) if power.max() > 0 and floor > 0 else (math.inf if power.max() > 0 else 0.0)
    log.debug("autofocus: brightest pixel %.1f dB above the background", contrast_db)
    if contrast_db >= options.min_contrast_db:
        return ""
    note = (f"nothing to focus on: the brightest pixel stands {contrast_db:.1f} dB above the background, "
            f"less than {options.min_contrast_db:g} dB")
    log.info("autofocus (%s): %s", options.method, note)
    return note


def _peak_power(g: GroupImages, phase: np.ndarray) -> float:
    """Power of the brightest estimation pixel of the group images' sum under ``phase`` [Q, T]."""
    img = g.image(phase) * g.weight.reshape(-1, TILE)
    return float(np.max(img.real.astype(np.float64) ** 2 + img.imag.astype(np.float64) ** 2))


def estimate_on_group_images(g: GroupImages, options: AutofocusOptions) -> AutofocusResult:
    """The track error from group images already formed (``estimate_track_error``'s second half; the live
    strip map keeps its tiles' group images and calls this once a tile is complete)."""
    e0, _ = _entropy_and_gradient(g, np.zeros_like(g.c))
    delta, it = phase_gradient_autofocus(g, options)
    e1, _ = _entropy_and_gradient(g, g.phase(delta))
    model = None
    if options.method == "entropy":
        # The model refines PGA's estimate; whichever of the two leaves the lower entropy is kept (a model
        # too poor for the track, or a local minimum, never makes the result worse than its start).
        weight = np.abs(g.b).sum(axis=(0, 2)).astype(float)
        start = fit_track_model(g.time_s, delta, options.poly_order, options.sinusoids, weight)
        model, e_model, it2 = minimum_entropy(g, start, options.entropy_iterations)
        it += it2
        d_model = remove_line(g.time_s, evaluate_model(model, g.time_s))
        peak_pga, peak_model = _peak_power(g, g.phase(delta)), _peak_power(g, g.phase(d_model))
        if e_model < e1 and peak_model >= MODEL_PEAK_KEEP * peak_pga:
            delta = d_model
            e1, _ = _entropy_and_gradient(g, g.phase(delta))
        elif e_model < e1:
            # Seen on a 0.05 m aperture under a Taylor taper: a sixth-order bend of millimetres that lowered
            # the entropy by pushing the target out of the pixels, and moved its peak 2 cm.
            log.info("autofocus (entropy): the model lowers the entropy but also the brightest pixel (%.1f dB); "
                     "keeping PGA's estimate", 10 * math.log10(peak_model / peak_pga))
            model = None
        else:
            log.info("autofocus (entropy): the model did not beat PGA's estimate (%.4f against %.4f); keeping PGA's", e_model, e1)
            model = None
    applied = e1 < e0
    note = "" if applied else "the estimate did not sharpen the image; left unapplied"
    if not applied:
        delta, model = np.zeros(g.b.shape[1]), None
        e1 = e0
    log.info("autofocus (%s): %d groups, %d pixels, entropy %.4f -> %.4f%s", options.method, g.b.shape[1],
             int(g.weight.sum()), e0, e1, f" ({note})" if note else "")
    return AutofocusResult(TrackError(g.time_s, delta, options.method, model), e0, e1, applied, int(g.weight.sum()),
                           g.b.shape[1], it, note)


def corrected_block(blk: ProfileBlock, track_error: TrackError) -> ProfileBlock:
    """The block with its antennas moved along its direction by the track error."""
    d = track_error.at(blk.time_s)[:, None] * blk.direction
    return dataclasses.replace(blk, tx_m=blk.tx_m + d, rx_m=blk.rx_m + d)


def backproject_blocks(blocks: Iterable[ProfileBlock], points_m: np.ndarray, track_error: TrackError | None = None,
                       mode: str = "linear") -> np.ndarray:
    """Backproject blocks onto ``points_m`` [..., 3], with the antennas moved by ``track_error``."""
    out = np.zeros(points_m.shape[:-1], np.complex128)
    for blk in blocks:
        if track_error is not None:
            blk = corrected_block(blk, track_error)
        backproject(blk.profiles, blk.tx_m, blk.rx_m, points_m, reference_range_m=blk.reference_range_m, mode=mode, out=out)
    return out


# -- vibration -------------------------------------------------------------------------------------------
@dataclasses.dataclass
class VibrationFit:
    """A sinusoid A sin(2 pi f t + phase) read off a track error (t from the track error's time origin)."""

    frequency_hz: float
    amplitude_m: float
    phase_rad: float
    residual_rms_m: float


def fit_vibration(track_error: TrackError, poly_order: int = 1) -> VibrationFit:
    """Frequency, amplitude and phase of the strongest sinusoid in an estimated track error.

    The offset and drift (and, with ``poly_order`` >= 2, a slow bend) are fitted beside it and set aside: the
    estimate does not know them. The fit is made on the estimated displacement, whichever estimator made it:
    over an aperture of one or two periods a sinusoid and a bend are far from orthogonal, so the entropy
    model's own split between them is not a measurement of either, while their sum is. A track error with
    no oscillation of a cycle or more over its span raises ValueError.
    """
    t0, _, coef, freqs, resid = _fit_sinusoids(track_error.time_s, track_error.displacement_m, poly_order, 1)
    if not freqs:
        raise ValueError("the track error holds no oscillation of a cycle or more over its span")
    n_poly = max(poly_order - 1, 0)
    f, a, b = freqs[0], coef[2 + n_poly], coef[3 + n_poly]
    # a cos(w (t - t0)) + b sin(w (t - t0)) = A sin(w t + phase)
    amp = math.hypot(a, b)
    phase = math.atan2(a, b) - 2 * math.pi * f * t0
    return VibrationFit(float(f), float(amp), float(math.remainder(phase, 2 * math.pi)), float(resid))
