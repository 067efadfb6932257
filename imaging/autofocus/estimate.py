"""Estimating a track error from an image: the estimation pixels, the group images, the chosen method
(``imaging.autofocus.registry``), the decision whether to apply it (by default the two half-bands' estimates
must agree, ``imaging.autofocus.consistency``; else the contrast gate), and the rule that a result which
does not sharpen the image is left unapplied; and backprojection on the corrected track."""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Iterable

import numpy as np

from imaging.autofocus.consistency import consistency_of, half_band_blocks
from imaging.autofocus.subapertures import GroupImages, entropy_and_gradient, group_images, image_entropy
from imaging.autofocus.options import AutofocusOptions, AutofocusResult, ProfileBlock
from imaging.autofocus.registry import METHODS
from imaging.autofocus.weak_point import point_check
from imaging.backprojection import backproject, patch_order
from imaging.core.track_error import TrackError

log = logging.getLogger("sarbot.imaging.autofocus")


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
    note = nothing_to_focus_on(image, options) if options.decision == "contrast" else ""
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
    g = group_images(blocks(), pixels, options.groups, (t_lo, t_hi))
    halves = None
    if options.decision == "consistency":
        halves = tuple(group_images(half_band_blocks(blocks(), h), pixels, options.groups, (t_lo, t_hi)) for h in (0, 1))
    return estimate_on_group_images(g, options, halves)


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



def estimate_on_group_images(g: GroupImages, options: AutofocusOptions,
                             halves: tuple[GroupImages, GroupImages] | None = None) -> AutofocusResult:
    """The track error from group images already formed (``estimate_track_error``'s second half; the live
    strip map keeps its tiles' group images and calls this once a tile is complete), by the method
    ``options.method`` names in ``METHODS``.

    ``halves``: the same groups imaged from the lower and from the upper half-band (``split_band``). Given
    them, the method estimates on each too and the estimate is applied only where the two agree and it
    agrees with them (``AutofocusResult.consistency``); without them only the entropy decides.
    """
    e0, _ = entropy_and_gradient(g, np.zeros_like(g.c))
    delta, model, it = METHODS[options.method](g, options)
    delta = np.asarray(delta, float)
    if delta.shape != g.time_s.shape:
        raise ValueError(f"autofocus method {options.method!r} gave {delta.shape} displacements for "
                         f"{g.time_s.size} groups")
    e1, _ = entropy_and_gradient(g, g.phase(delta))
    applied = e1 < e0
    note = "" if applied else "the estimate did not sharpen the image; left unapplied"
    consistency = None
    if halves is not None:
        lower, upper = (np.asarray(METHODS[options.method](h, options)[0], float) for h in halves)
        # The full band may always depart from the halves' common part by 0.1 rad of two-way phase.
        consistency, agreed = consistency_of(g.time_s, lower, upper, delta, options.false_alarm, options.poly_order,
                                             max(options.sinusoids, 1), floor_m=0.1 / (2.0 * g.k))
        log.info("autofocus (%s): %s", options.method, consistency.describe())
        if agreed is None and consistency.passed:
            # The halves agree and the full band departs from them (PGA's estimate at the aperture's ends, where
            # its window over the full band's scatterers differs): what two disjoint halves of the data agree on
            # is the estimate that is consistent, so that is what may be applied (its smooth part where only
            # that agrees). It agrees with itself by construction.
            consistency = dataclasses.replace(consistency, applied_agrees=True)
            delta = consistency.common_m
            model = {"kind": "half-band common part", "method": options.method, "model": model}
            e1, _ = entropy_and_gradient(g, g.phase(delta))
            applied = e1 < e0
            note = ("the full-band estimate departs from the half-band estimates; their common part applied" if applied
                    else "the full-band estimate departs from the half-band estimates, and their common part did "
                         "not sharpen the image; left unapplied")
        elif agreed is None:
            applied = False
            note = "the half-band estimates disagree; left unapplied"
        elif consistency.scope == "smooth":
            # Only the smooth part is consistent: that part is applied, the per-group rest is noise.
            delta, model = agreed, {"kind": "consistent smooth part", "method": options.method, "model": model}
            e1, _ = entropy_and_gradient(g, g.phase(delta))
            applied = e1 < e0
            note = "" if applied else "the consistent part did not sharpen the image; left unapplied"
        if not applied:
            # Nothing the halves agree on sharpens the image: a target too weak for the method's estimates may
            # still hold its track error's lowest orders in its own phase history (imaging.autofocus.weak_point).
            consistency = consistency.with_point(point_check(g, halves, options.false_alarm))
            if consistency.scope == "point":
                log.info("autofocus (%s): %s", options.method, consistency.describe())
                # The fit maximises the point's own power; the entropy of an image that is mostly noise
                # need not fall with it, so it does not decide here.
                delta = consistency.point.displacement_m
                model = {"kind": "weak point", "method": options.method, "legendre_orders": [2, consistency.point.dof + 1]}
                e1, _ = entropy_and_gradient(g, g.phase(delta))
                applied, note = True, ""
    if not applied:
        delta, model = np.zeros(g.b.shape[1]), None
        e1 = e0
    log.info("autofocus (%s): %d groups, %d pixels, entropy %.4f -> %.4f%s", options.method, g.b.shape[1],
             int(g.weight.sum()), e0, e1, f" ({note})" if note else "")
    return AutofocusResult(TrackError(g.time_s, delta, options.method, model), e0, e1, applied, int(g.weight.sum()),
                           g.b.shape[1], it, note, consistency)


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

