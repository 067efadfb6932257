"""Image quality: peak, cuts, half-power widths, side lobes, SNR, integration gain, vibration inverse.

Plain functions on arrays. Widths are half-power widths at -3.0 dB (see docs/conventions.md). Cuts are taken along
the radar's look direction (range) and across it (cross-range) through the peak.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.ndimage
import scipy.optimize
import scipy.special

from imaging.core.constants import SPEED_OF_LIGHT_MPS
from imaging.core.windows import half_power_width, window_width_factor


# -- theory -----------------------------------------------------------------------------------------
def range_resolution_theory_m(bandwidth_hz: float, window: str = "hann") -> float:
    """Half-power range width: factor * c / (2 B)."""
    return window_width_factor(window) * SPEED_OF_LIGHT_MPS / (2.0 * bandwidth_hz)


def cross_range_resolution_theory_m(wavelength_m: float, range_m: float, aperture_m: float, window: str = "rectangular") -> float:
    """Half-power cross-range width: factor * lambda * r0 / (2 La), the factor that of the aperture's
    slow-time ``window`` (rectangular: a uniformly weighted aperture, 0.88)."""
    return window_width_factor(window) * wavelength_m * range_m / (2.0 * aperture_m)


# -- peak and cuts ------------------------------------------------------------------------------------
def find_peak(image: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, near_m=None, radius_m: float = 0.1):
    """Peak of |image| (2-D, [ny, nx]), optionally the highest within ``radius_m`` of ``near_m`` (x, y).

    Returns (iy, ix) and the position (x, y) refined by a parabola through the peak and its neighbours
    (power in dB) in each axis.
    """
    mag = np.abs(image)
    if near_m is not None:
        xx, yy = np.meshgrid(x_m, y_m)
        mask = (xx - near_m[0]) ** 2 + (yy - near_m[1]) ** 2 <= radius_m ** 2
        if not mask.any():
            raise ValueError(f"no pixel within {radius_m} m of {tuple(near_m)}")
        mag = np.where(mask, mag, 0.0)
    iy, ix = np.unravel_index(int(np.argmax(mag)), mag.shape)
    return (int(iy), int(ix)), (_refine(mag[iy, :], ix, x_m), _refine(mag[:, ix], iy, y_m))


def _refine(values: np.ndarray, k: int, axis: np.ndarray) -> float:
    if 0 < k < values.size - 1 and np.all(values[k - 1:k + 2] > 0):
        a, b, c = 20 * np.log10(values[k - 1:k + 2])
        denom = a - 2 * b + c
        offset = 0.5 * (a - c) / denom if denom != 0 else 0.0
        return float(axis[k] + offset * (axis[1] - axis[0]))
    return float(axis[k])


def cut(image: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, centre_m, direction, half_length_m: float, n: int = 801):
    """Complex values along a line through ``centre_m`` (x, y) in ``direction`` (x, y), cubic-spline interpolated.

    Returns (s_m, values) with s the signed distance from the centre; samples that would fall outside
    the image are left out.
    """
    d = np.asarray(direction, float)[:2]
    d = d / np.linalg.norm(d)
    s = np.linspace(-half_length_m, half_length_m, n)
    px = (centre_m[0] + s * d[0] - x_m[0]) / (x_m[1] - x_m[0])
    py = (centre_m[1] + s * d[1] - y_m[0]) / (y_m[1] - y_m[0])
    # Only the part of the line inside the image counts.
    inside = (px >= 0) & (px <= x_m.size - 1) & (py >= 0) & (py <= y_m.size - 1)
    s, px, py = s[inside], px[inside], py[inside]
    coords = np.vstack([py, px])
    re = scipy.ndimage.map_coordinates(image.real, coords, order=3, mode="constant", cval=0.0)
    im = scipy.ndimage.map_coordinates(image.imag, coords, order=3, mode="constant", cval=0.0)
    return s, re + 1j * im


def mainlobe_bounds(power: np.ndarray, k: int) -> tuple[int, int]:
    """Indices of the first minima on either side of the peak at ``k``."""
    left = k
    while left > 0 and power[left - 1] < power[left]:
        left -= 1
    right = k
    while right < power.size - 1 and power[right + 1] < power[right]:
        right += 1
    return left, right


def sidelobe_levels(values: np.ndarray) -> tuple[float, float]:
    """Peak side-lobe level and integrated side-lobe ratio (both dB) of a cut through a peak."""
    power = np.abs(values) ** 2
    k = int(np.argmax(power))
    left, right = mainlobe_bounds(power, k)
    side = np.concatenate([power[:left], power[right + 1:]])
    main = power[left:right + 1]
    pslr = 10 * np.log10(side.max() / power[k]) if side.size else -np.inf
    islr = 10 * np.log10(side.sum() / main.sum()) if side.size else -np.inf
    return float(pslr), float(islr)


def image_snr_db(image: np.ndarray, peak_index, exclude_px: tuple[int, int]) -> float:
    """Peak power over the mean power of the image outside a box of +-exclude_px (y, x) around the peak."""
    power = np.abs(image) ** 2
    iy, ix = peak_index
    mask = np.ones(power.shape, bool)
    mask[max(0, iy - exclude_px[0]):iy + exclude_px[0] + 1, max(0, ix - exclude_px[1]):ix + exclude_px[1] + 1] = False
    if not mask.any():
        return float("nan")
    return float(10 * np.log10(power[iy, ix] / power[mask].mean()))


def fit_integration_gain(n_frames, snr_db) -> tuple[float, float]:
    """Fit SNR = g0 * N^alpha over numbers of integrated frames; returns (alpha, g0 in dB).

    alpha = 1 is perfectly coherent integration, 0.5 non-coherent (see docs/signal-model.md).
    """
    n = np.log10(np.asarray(n_frames, float))
    s = np.asarray(snr_db, float) / 10.0
    if n.size < 2 or np.ptp(n) == 0:
        raise ValueError("need images of at least two different frame counts to fit an integration gain")
    alpha, g0 = np.polyfit(n, s, 1)
    return float(alpha), float(10 * g0)


# -- vibration inverse ---------------------------------------------------------------------------------
def vibration_frequency_hz(sidelobe_offset_m: float, range_m: float, speed_mps: float, wavelength_m: float) -> float:
    """f_vib = 2 v / lambda * x / sqrt(x^2 + r0^2) for a side lobe at cross-range offset x."""
    x = abs(sidelobe_offset_m)
    return 2.0 * speed_mps / wavelength_m * x / math.hypot(x, range_m)


def vibration_amplitude_m(sidelobe_level_db: float, wavelength_m: float) -> float:
    """A_vib from the side-lobe level L = 20 log10(J1(a)/J0(a)), a = 2 pi 2 A / lambda."""
    target = 10.0 ** (sidelobe_level_db / 20.0)
    # J1/J0 rises monotonically from 0 to +inf on (0, j0,1 = 2.4048): one root.
    a = scipy.optimize.brentq(lambda a: scipy.special.j1(a) / scipy.special.j0(a) - target, 1e-9, 2.4048 - 1e-9)
    return float(a * wavelength_m / (4.0 * math.pi))


def vibration_sidelobe_level_db(amplitude_m: float, wavelength_m: float) -> float:
    """Forward model: L = 20 log10(J1(a)/J0(a))."""
    a = 4.0 * math.pi * amplitude_m / wavelength_m
    return float(20 * np.log10(abs(scipy.special.j1(a) / scipy.special.j0(a))))


def paired_sidelobes(s_m: np.ndarray, values: np.ndarray, min_offset_m: float = 0.0):
    """The strongest side lobe on each side of the main lobe of a cut.

    Returns (offset_m, level_db): the mean |offset| of the left and right lobes from the peak and their
    mean level relative to the peak (each refined by a parabola in dB).
    """
    power = np.abs(values) ** 2
    k = int(np.argmax(power))
    left, right = mainlobe_bounds(power, k)
    peak_db = 10 * np.log10(power[k])
    s_peak = _refine(np.sqrt(power), k, s_m)
    result = []
    for lo, hi in ((0, left), (right + 1, power.size)):
        region = np.arange(lo, hi)
        region = region[np.abs(s_m[region] - s_peak) >= min_offset_m]
        if region.size == 0:
            raise ValueError("no side lobe found in the cut")
        j = int(region[np.argmax(power[region])])
        pos = _refine(np.sqrt(power), j, s_m)
        level = 10 * np.log10(power[j]) - peak_db
        if 0 < j < power.size - 1:
            a, b, c = 10 * np.log10(power[j - 1:j + 2])
            denom = a - 2 * b + c
            if denom != 0:
                off = 0.5 * (a - c) / denom
                level = b - 0.25 * (a - c) * off - peak_db
        result.append((abs(pos - s_peak), level))
    return float(np.mean([r[0] for r in result])), float(np.mean([r[1] for r in result])), result


# -- everything about one target ------------------------------------------------------------------------
def analyze_target(image: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, look_direction, *, near_m=None,
                   radius_m: float = 0.1, half_length_m: float = 0.3, n: int = 1201) -> dict:
    """Peak position, range and cross-range cuts, widths, side lobes and SNR of the target at the peak."""
    (iy, ix), (px, py) = find_peak(image, x_m, y_m, near_m, radius_m)
    look = np.asarray(look_direction, float)[:2]
    look = look / np.linalg.norm(look)
    across = np.array([-look[1], look[0]])
    out = {"peak_m": [px, py], "peak_index": [iy, ix], "peak_amplitude": float(np.abs(image[iy, ix]))}
    widths = {}
    for name, d in (("range", look), ("cross_range", across)):
        s, v = cut(image, x_m, y_m, (px, py), d, half_length_m, n)
        pslr, islr = sidelobe_levels(v)
        width = half_power_width(v, spacing=s[1] - s[0])
        out[name] = {"half_power_width_m": width, "pslr_db": pslr, "islr_db": islr}
        widths[name] = width
    dx, dy = x_m[1] - x_m[0], y_m[1] - y_m[0]
    # Exclude a box of 5 widths around the peak from the background estimate.
    ex = int(np.ceil(5 * max(widths.values()) / min(dx, dy))) if np.all(np.isfinite(list(widths.values()))) else 10
    out["snr_db"] = image_snr_db(image, (iy, ix), (ex, ex))
    return out


def compare_with_theory(result: dict, image: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, attrs: dict,
                        wavelength_m: float, *, vibration: bool = False, half_length_m: float = 0.3) -> dict:
    """Add to ``analyze_target``'s ``result`` what theory expects of the image (its ``attrs`` say the
    aperture and bandwidth): range and cross-range half-power widths and their ratios to theory, and with
    ``vibration`` the boresight vibration (f_vib, A_vib) inferred from paired cross-range side lobes.

    Images without ``aperture_centre_m`` and ``aperture_length_m`` (a strip map, another tool's image)
    have no theory to compare with; ``result`` comes back unchanged.
    """
    if "aperture_centre_m" not in attrs or "aperture_length_m" not in attrs:
        return result
    centre = np.asarray(attrs["aperture_centre_m"])
    peak = result["peak_m"]
    r0 = float(np.hypot(peak[0] - centre[0], peak[1] - centre[1]))
    aperture = float(attrs["aperture_length_m"])
    theory = {
        "range_half_power_width_m": range_resolution_theory_m(float(attrs["bandwidth_hz"]), str(attrs.get("window", "hann"))),
        "cross_range_half_power_width_m": cross_range_resolution_theory_m(
            wavelength_m, r0, aperture, str(attrs.get("aperture_window", "rectangular"))),
        "aperture_length_m": aperture,
    }
    result["range_to_target_m"] = r0
    result["theory"] = theory
    result["range"]["ratio_to_theory"] = result["range"]["half_power_width_m"] / theory["range_half_power_width_m"]
    result["cross_range"]["ratio_to_theory"] = (result["cross_range"]["half_power_width_m"]
                                                / theory["cross_range_half_power_width_m"])
    if vibration:
        look = np.asarray(attrs.get("look_direction", [0.0, 1.0, 0.0]), float)[:2]
        look = look / np.linalg.norm(look)
        s, v = cut(image, x_m, y_m, peak, (-look[1], look[0]), half_length_m, 2001)
        offset, level, _ = paired_sidelobes(s, v, min_offset_m=2 * result["cross_range"]["half_power_width_m"])
        result["vibration"] = {
            "sidelobe_offset_m": offset, "sidelobe_level_db": level,
            "frequency_hz": vibration_frequency_hz(offset, r0, float(attrs.get("speed_mps", 0.0)), wavelength_m),
            "amplitude_m": vibration_amplitude_m(level, wavelength_m),
        }
    return result
