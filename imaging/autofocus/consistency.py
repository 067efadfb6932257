"""Whether a track-error estimate is real: the same track error estimated from two disjoint halves of the
band must agree.

A track error is a path-length error: profile p reaches every scatterer ``2 delta_p c`` longer or shorter,
so at every frequency f of the chirp it adds the phase ``4 pi f delta_p c / c0``. The profiles compressed
from the lower and from the upper half of the chirp's samples (``split_band``: disjoint frequencies) are two
independent looks at the same track: each half's group images give an estimate of delta (in metres, each
at its own carrier), and for a real track error the two agree. What an estimator fits that is not a track
error does not agree: the speckle of distributed clutter decorrelates between disjoint sub-bands (a
resolution cell of one half holds scatterers spread over a whole range cell of it: the other half sees them
at phases a full turn apart), and thermal noise in disjoint samples is independent. A point target's phase
history is the same in both.

The test (``consistency_of``): with ``a`` and ``b`` the two estimates (each less its line), their common
part ``s = (a + b) / 2`` and half their difference ``d = (a - b) / 2``. Where the two are independent fits
of the same kind to nothing (clutter, noise), s and d have one distribution, and
``ratio = |s|^2 / |d|^2`` is F-distributed with as many degrees of freedom as the estimates hold
independent values; a real track error x gives ``ratio ~ 1 + |x|^2 / |d|^2``. The degrees of freedom are
counted from the difference's spectrum (``2 (sum P)^2 / sum P^2`` over its periodogram: one per group for
white noise, a few for a smooth bend), and the estimate passes where the ratio exceeds the F
distribution's quantile at ``1 - false_alarm``. The uncertainty of an estimate is ``rms(d)``: what the two
halves disagree by. See docs/signal-model.md for the phase model.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING

import numpy as np
import scipy.stats

from imaging.core.track_error import remove_line
from imaging.range_compression import RangeProfiles, range_compress

if TYPE_CHECKING:
    from imaging.autofocus.weak_point import PointCheck

#: The false-alarm rate the consistency test is held to by default: the chance that two estimates fitted to
#: nothing (clutter, noise) pass as one track error.
FALSE_ALARM = 0.01


def band_samples(profiles: RangeProfiles) -> np.ndarray:
    """The windowed fast-time samples [P, n] the profiles were compressed from (their own ``samples``, else
    the inverse FFT of the zero-padded, possibly centred and range-signed spectrum; exact)."""
    if profiles.samples is not None:
        return np.asarray(profiles.samples).reshape(profiles.data.shape[0], -1)
    if not profiles.bandwidth_hz or not profiles.frequency_step_hz:
        raise ValueError("splitting the band needs profiles that know their bandwidth and frequency step")
    n = int(round(profiles.bandwidth_hz / profiles.frequency_step_hz))
    m = int(round((profiles.carrier_hz - profiles.f0_hz) / profiles.frequency_step_hz))
    data = np.asarray(profiles.data)
    if profiles.range_start_m < 0:  # signed: range zero was put in the middle
        data = np.fft.ifftshift(data, axes=-1)
    buf = np.fft.ifft(data, axis=-1)
    n_fft = buf.shape[-1]
    # Centred compression wrote sample i at position i - m (mod n_fft).
    return np.concatenate([buf[:, n_fft - m:], buf[:, :n - m]], axis=1).astype(np.complex64) if m else \
        buf[:, :n].astype(np.complex64)


def split_band(profiles: RangeProfiles) -> tuple[RangeProfiles, RangeProfiles]:
    """The profiles compressed from the lower and from the upper half of the chirp's samples: two disjoint
    sub-bands, each at its own carrier, half the bandwidth (twice the range cell), same oversampling."""
    samples = band_samples(profiles)
    n = samples.shape[1]
    half = n // 2
    oversample = max(1, int(round(profiles.n_bins / n)))
    signed = profiles.range_start_m < 0
    out = []
    for lo, hi in ((0, half), (n - half, n)):
        # The full band's window is kept (each half holds its part of it): the estimate needs the phase
        # across slow time, not low range side lobes.
        out.append(range_compress(samples[:, lo:hi], profiles.f0_hz + lo * profiles.frequency_step_hz,
                                  profiles.frequency_step_hz, window="rectangular", oversample=oversample,
                                  signed=signed, keep_samples=False, guarded=True))
    return out[0], out[1]


def half_band_blocks(blocks: Iterable, half: int) -> Iterator:
    """The blocks (``ProfileBlock``) with their profiles from the lower (``half=0``) or upper (1) half-band."""
    for blk in blocks:
        yield dataclasses.replace(blk, profiles=split_band(blk.profiles)[half])


def effective_dof(*series: np.ndarray) -> float:
    """Independent values a series holds, from its periodogram (of several series of one length: their
    periodograms added): ``2 (sum P)^2 / sum P^2`` (white noise: about one per sample; a smooth bend or a
    random walk, a few), at least 1."""
    p = sum(np.abs(np.fft.rfft(np.asarray(v, float))) ** 2 for v in series)
    p = p[1:]  # the mean is no information (the line is removed already)
    if p.size == 0 or p.sum() <= 0:
        return 1.0
    return float(max(1.0, min(series[0].size, 2.0 * p.sum() ** 2 / (p ** 2).sum())))


def smooth_basis(time_s: np.ndarray, lower_m: np.ndarray, upper_m: np.ndarray, poly_order: int, sinusoids: int
                 ) -> np.ndarray:
    """Columns [Q, K] spanning a low-order track error: Legendre P2..P_poly_order over the span and a cosine
    and sine at each of ``sinusoids`` frequencies, orthonormalised against the line and each other.

    The frequencies are the periodogram bins where ``|A|^2 |B|^2`` (the two estimates' spectra) is largest:
    a choice blind to whether the two agree in sign, so it inflates the common part and the difference
    alike and leaves the test's null distribution as it was."""
    from imaging.autofocus.track_model import _legendre

    t = np.asarray(time_s, float)
    tau = (t - 0.5 * (t.min() + t.max())) / max(0.5 * np.ptp(t), 1e-12)
    cols = [np.ones_like(tau), tau, _legendre(tau, poly_order)]
    n = t.size
    spec = (np.abs(np.fft.rfft(lower_m)) * np.abs(np.fft.rfft(upper_m))) ** 2
    freq = np.fft.rfftfreq(n, float(np.ptp(t)) / max(n - 1, 1))
    spec[: min(2, spec.size)] = 0  # below one cycle over the span: a bend, the polynomial's
    for i in np.argsort(spec)[::-1][:sinusoids]:
        if spec[i] > 0:
            w = 2 * math.pi * freq[i] * (t - t.min())
            cols.append(np.column_stack([np.cos(w), np.sin(w)]))
    q, _ = np.linalg.qr(np.column_stack(cols))
    return q[:, 2:]  # the line's two columns come first: what is left is orthogonal to it


def _f_test(common: np.ndarray, diff: np.ndarray, dof: float, false_alarm: float) -> tuple[float, float, bool]:
    p_common, p_diff = float(np.sum(common ** 2)), float(np.sum(diff ** 2))
    critical = float(scipy.stats.f.ppf(1.0 - false_alarm, dof, dof))
    ratio = p_common / p_diff if p_diff > 0 else (math.inf if p_common > 0 else 0.0)
    return min(ratio, 1e12), critical, bool(ratio > critical)


@dataclasses.dataclass
class Consistency:
    """Two half-band estimates of one track error, compared, group by group and in their smooth part.

    ``ratio``: power of their common part over power of half their difference, group by group (1 for two
    fits to nothing, large for a real track error); ``critical_ratio``: the F quantile at
    ``1 - false_alarm / 2`` for ``dof`` degrees of freedom; the same for the parts of both in
    ``smooth_basis`` (``smooth_ratio``, ``smooth_critical_ratio``, ``smooth_dof``): a weak target's
    per-group values are noise, a bend and a vibration are a few numbers. ``scope``: "per-group" where the
    estimate agrees group by group, "smooth" where only its smooth part does (that part is what is
    applied), "point" where nothing the halves agree on sharpens the image but the brightest pixel is a
    weak point whose own low-order fit agrees in both halves (``point``, ``imaging.autofocus.weak_point``;
    that fit is applied), "" where none. ``common_rms_m`` and ``uncertainty_m``: rms of the common part and of half the difference (the
    estimate's uncertainty), in the scope that decided (per group where none did; for "point", the fit's
    rms and its Cramer-Rao bound). ``applied_agrees``: the estimate to apply lies within the critical ratio
    of the common part. ``point``: the weak-point test, where it was made (nothing agreed was applied).
    ``common_m``: the common part itself in the scope that decided [Q] (line removed; its smooth part for
    "smooth"): what the two halves agree on, which may be applied where the estimate departs from it.
    """

    ratio: float
    critical_ratio: float
    dof: float
    smooth_ratio: float
    smooth_critical_ratio: float
    smooth_dof: float
    false_alarm: float
    scope: str
    common_rms_m: float
    uncertainty_m: float
    applied_agrees: bool
    point: PointCheck | None = None
    common_m: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def passed(self) -> bool:
        return bool(self.scope)

    @property
    def margin_db(self) -> float:
        """The single number: how far the deciding ratio stands above its critical value (dB; the better of
        the tests made; positive: consistent)."""
        return max(10 * math.log10(max(self.ratio, 1e-12) / self.critical_ratio),
                   10 * math.log10(max(self.smooth_ratio, 1e-12) / self.smooth_critical_ratio),
                   -math.inf if self.point is None else self.point.margin_db)

    def with_point(self, point: PointCheck) -> Consistency:
        """This comparison with the weak-point test made: scope "point" where it passed (made where
        nothing the halves' estimates agree on was applied)."""
        if not point.passed:
            return dataclasses.replace(self, point=point)
        return dataclasses.replace(self, point=point, scope="point", applied_agrees=True,
                                   common_rms_m=float(np.sqrt(np.mean(point.displacement_m ** 2))),
                                   uncertainty_m=point.uncertainty_m)

    def as_attrs(self) -> dict:
        """The image file's attributes (docs/formats/image.md)."""
        return {"autofocus_consistency_margin_db": self.margin_db, "autofocus_consistency_scope": self.scope or "none",
                "autofocus_consistency_ratio_db": 10 * math.log10(max(self.ratio, 1e-12)),
                "autofocus_consistency_smooth_ratio_db": 10 * math.log10(max(self.smooth_ratio, 1e-12)),
                "autofocus_consistency_false_alarm": self.false_alarm,
                "autofocus_consistent": int(self.passed and self.applied_agrees),
                "autofocus_uncertainty_m": self.uncertainty_m, "autofocus_common_rms_m": self.common_rms_m,
                **({} if self.point is None else {
                    "autofocus_point_contrast_db": 10 * math.log10(max(self.point.contrast, 1e-12)),
                    "autofocus_point_margin_db": self.point.margin_db})}

    def describe(self) -> str:
        verdict = {"per-group": "consistent group by group", "smooth": "consistent in its smooth part",
                   "point": "inconsistent, but a weak point's low-order fit agrees in both halves",
                   "": "inconsistent"}[self.scope]
        if self.scope and not self.applied_agrees:
            verdict += ", but the full-band estimate departs from it"
        return (f"half-band estimates {1e3 * self.common_rms_m:.3f} mm rms in common, uncertainty "
                f"{1e3 * self.uncertainty_m:.3f} mm; margin {self.margin_db:+.1f} dB at {100 * self.false_alarm:g} % "
                f"false alarms: {verdict}")


def consistency_of(time_s: np.ndarray, lower_m: np.ndarray, upper_m: np.ndarray, applied_m: np.ndarray | None = None,
                   false_alarm: float = FALSE_ALARM, poly_order: int = 6, sinusoids: int = 1, floor_m: float = 0.0
                   ) -> tuple[Consistency, np.ndarray | None]:
    """Compare two estimates of one track error from disjoint data (metres at the group times [Q]), and the
    estimate to apply, if any, against their common part (see the module's docstring). Returns the
    comparison and what may be applied: ``applied_m`` where it agrees group by group, its smooth part where
    only that agrees, else None. ``floor_m``: the rms by which the estimate to apply may always depart from
    the common part (where the halves agree to micrometres, the full band's own window and carrier differ
    by more than that)."""
    t = np.asarray(time_s, float)
    a, b = remove_line(t, np.asarray(lower_m, float)), remove_line(t, np.asarray(upper_m, float))
    common, diff = 0.5 * (a + b), 0.5 * (a - b)
    each = 0.5 * false_alarm  # two tests: together at most the stated false-alarm rate
    # From both parts' spectra: under the null they have one spectrum, and one periodogram alone is too
    # noisy a count where a few bins hold most of the power (a random walk's).
    dof = effective_dof(common, diff)
    ratio, critical, passed = _f_test(common, diff, dof, each)
    basis = smooth_basis(t, a, b, poly_order, sinusoids)
    s_ratio, s_critical, s_passed = _f_test(basis.T @ common, basis.T @ diff, float(basis.shape[1]), each)
    applied = None if applied_m is None else remove_line(t, np.asarray(applied_m, float))
    scope, agrees, out = "", True, None
    if passed:
        scope, scope_common, scope_diff = "per-group", common, diff
        if applied is not None:
            agrees = float(np.sum((applied - common) ** 2)) <= critical * float(np.sum(diff ** 2)) + t.size * floor_m ** 2
            out = applied if agrees else None
    elif s_passed:
        scope = "smooth"
        scope_common, scope_diff = basis @ (basis.T @ common), basis @ (basis.T @ diff)
        if applied is not None:
            smooth = basis @ (basis.T @ applied)
            agrees = float(np.sum((smooth - scope_common) ** 2)) <= s_critical * float(np.sum(scope_diff ** 2)) + t.size * floor_m ** 2
            out = smooth if agrees else None
    else:
        scope_common, scope_diff = common, diff
    result = Consistency(ratio, critical, dof, s_ratio, s_critical, float(basis.shape[1]), false_alarm, scope,
                         float(np.sqrt(np.mean(scope_common ** 2))), float(np.sqrt(np.mean(scope_diff ** 2))), agrees,
                         common_m=scope_common)
    return result, out
