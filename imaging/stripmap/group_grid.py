"""A tile's group images on pixels fine enough for autofocus: each group's own phase taken out, the smooth
rest interpolated onto finer pixels, the phase put back.

Why. A map's pixels (1 cm by default) may be coarser than its cross-range resolution (lambda R / 2L: 5 mm at
1.5 m for a 0.6 m aperture). The map is then undersampled, and so is the sum of a tile's group images: group
q's phase turns across the pixels at the spatial frequency 2 k u_q (u_q the unit vector from its antenna to
the pixels), and where the groups' frequencies span more than 2 pi per pixel, the groups at the aperture's
ends alias onto each other. Autofocus on such pixels (entropy, PGA's adjoint) cannot tell a group's phase
from one that moves its part of the aperture by a whole pixel: its estimate of a wrong along-track speed is a
sawtooth, ramps that shift a part of the aperture by a pixel (lambda R / 2 over it: 0.8 mm at 1.6 m for 1 cm
pixels) with jumps where a group's frequency crosses the grid's band edge. A group alone is a short
sub-aperture: once its phase ``exp(-j k r_q(x))`` (r_q the two-way range from its antenna phase centre) is taken
out, what is left varies over the range resolution and the sub-aperture's width, both several pixels, so it
interpolates well.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.ndimage

#: Finer pixels than the bare limit: each group's own extent widens the band a little.
BAND_MARGIN = 1.25


def upsampling_factors(k: float, antenna_m: np.ndarray, centre_m: np.ndarray, pixel_m: float,
                       margin: float = BAND_MARGIN) -> tuple[int, int]:
    """How many finer pixels per pixel, along world x and y, the sum of group images seen from ``antenna_m``
    [Q, 3] at ``centre_m`` [3] needs: the groups' spatial frequencies 2 k u_q span 2 k ptp(u) per axis, and a
    grid of spacing d carries 2 pi / d. ``k`` is the carrier wavenumber (rad/m)."""
    los = np.asarray(centre_m, float)[None, :] - np.asarray(antenna_m, float)
    u = los / np.linalg.norm(los, axis=1, keepdims=True)
    span = np.ptp(u[:, :2], axis=0)
    turns = margin * 2.0 * k * span * pixel_m / (2.0 * math.pi)
    return int(max(1, math.ceil(turns[0]))), int(max(1, math.ceil(turns[1])))


def finer_group_images(images: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, z_m: float, antenna_m: np.ndarray,
                       k: float, factors: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group images [Q, ny, nx] on pixels centred at ``x_m`` [nx], ``y_m`` [ny] (evenly spaced, height ``z_m``),
    seen from antenna phase centres ``antenna_m`` [Q, 3], on a grid ``factors`` (along x, along y) times finer
    over the same area. Returns the images [Q, ny * fy, nx * fx] complex64 and their pixel centres x, y."""
    fx, fy = factors
    images = np.asarray(images)
    x_m, y_m = np.asarray(x_m, float), np.asarray(y_m, float)
    dx = float(x_m[1] - x_m[0]) if x_m.size > 1 else 1.0
    dy = float(y_m[1] - y_m[0]) if y_m.size > 1 else 1.0
    xf = x_m[0] - 0.5 * dx + (np.arange(x_m.size * fx) + 0.5) * dx / fx
    yf = y_m[0] - 0.5 * dy + (np.arange(y_m.size * fy) + 0.5) * dy / fy
    # Fine pixel centres in the coarse grid's index coordinates (row, column).
    rows, cols = np.meshgrid((yf - y_m[0]) / dy, (xf - x_m[0]) / dx, indexing="ij")
    coords = np.stack([rows, cols])
    out = np.empty((images.shape[0], yf.size, xf.size), np.complex64)
    for q in range(images.shape[0]):
        turn_back = np.exp(1j * k * _two_way_range(antenna_m[q], x_m, y_m, z_m))
        smooth = images[q] * turn_back
        fine = (scipy.ndimage.map_coordinates(smooth.real, coords, order=3, mode="nearest")
                + 1j * scipy.ndimage.map_coordinates(smooth.imag, coords, order=3, mode="nearest"))
        out[q] = fine * np.exp(-1j * k * _two_way_range(antenna_m[q], xf, yf, z_m))
    return out, xf, yf


def _two_way_range(antenna_m: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, z_m: float) -> np.ndarray:
    """Twice the distance [ny, nx] from the antenna to the pixels: the range the backprojection's phase turns with."""
    dx = x_m[None, :] - antenna_m[0]
    dy = y_m[:, None] - antenna_m[1]
    return 2.0 * np.sqrt(dx ** 2 + dy ** 2 + (z_m - antenna_m[2]) ** 2)


def estimation_group_images(images: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, z_m: float, time_s: np.ndarray,
                            antenna_m: np.ndarray, direction: np.ndarray, k: float, range_resolution_m: float,
                            centre_m: np.ndarray, seen: np.ndarray):
    """The ``GroupImages`` autofocus estimates on for a tile whose pixels undersample its aperture: group
    images [Q, ny, nx] (pixel centres ``x_m``, ``y_m``) on the finer grid ``upsampling_factors`` asks for the
    groups that ``seen`` [Q] (bool) the scatterer at ``centre_m``; None where the tile's own pixels suffice.
    ``time_s``, ``antenna_m``, ``direction`` are the groups' (as ``assemble_group_images`` takes them)."""
    from imaging.autofocus import TILE, assemble_group_images
    from imaging.backprojection import patch_order

    pixel_m = float(min(x_m[1] - x_m[0], y_m[1] - y_m[0]))
    factors = upsampling_factors(k, np.asarray(antenna_m)[seen], centre_m, pixel_m)
    if factors == (1, 1):
        return None
    fine, xf, yf = finer_group_images(images, x_m, y_m, z_m, antenna_m, k, factors)
    n = xf.size * yf.size
    order = patch_order((yf.size, xf.size))
    order = np.arange(n) if order is None else order
    gx, gy = np.meshgrid(xf, yf)
    points = np.stack([gx.ravel(), gy.ravel(), np.full(n, z_m)], axis=1)[order]
    b = fine.reshape(fine.shape[0], n)[:, order]
    weight = np.ones(n, np.float32)
    pad = (-n) % TILE  # whole tiles of the group images' geometry, the padding weighted 0
    if pad:
        points = np.concatenate([points, np.repeat(points[-1:], pad, axis=0)])
        b = np.concatenate([b, np.zeros((b.shape[0], pad), b.dtype)], axis=1)
        weight = np.concatenate([weight, np.zeros(pad, np.float32)])
    return assemble_group_images(b, time_s, antenna_m, direction, points, weight, k, range_resolution_m)
