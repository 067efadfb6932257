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
``per-profile`` PGA's values refined group by group to the sharpest image (``sum |I|^4``): one free value
             per group, what a pulse-to-pulse random walk needs (``imaging.autofocus.per_profile``).
``combined`` the entropy model for the smooth part, then ``per-profile``'s refinement for the rest; the
             residual's spectrum is reported in the track error's model.
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

Whether an estimate is applied (``AutofocusOptions.decision``): by default ("consistency") the method
estimates the track error three times, from the whole band and from its lower and upper halves
(``consistency.split_band``: disjoint chirp frequencies, so independent noise and decorrelated speckle, but
the same path-length error), and the estimate is applied only where the two halves agree beyond what two
fits to nothing would at the false-alarm rate ``false_alarm`` (an F test of their common part against
their difference, group by group or in a low-order smooth part, ``consistency.consistency_of``) and the
whole band's estimate agrees with them; the comparison goes into ``AutofocusResult.consistency`` and the
image file. Diffuse clutter and noise, whose estimates are fits to speckle, are so left untouched
whatever the contrast gate says. The former rule stays as decision "contrast": an image (noise, diffuse
clutter) whose brightest pixel stands less than ``min_contrast_db`` above its background is left as it
is. The background is the median intensity of noise estimated from the dimmest tenth of the pixels; noise
alone reaches 13 dB above it at a million pixels, a point target tens of dB.

Where nothing the halves agree on sharpens the image, a weak point target is focused by its own phase
history: its pixel detected above the brightest speckle its background could give at the same false-alarm
rate, a bend (Legendre orders 2-3) fitted to that pixel alone, applied where both halves' fits agree
within their noise (``weak_point``).

Modules, one idea each: ``subapertures`` (the group images and their entropy), ``consistency`` (the
half-band estimates and their comparison), ``weak_point`` (the weak point's test and fit), ``pga``, ``track_model``
(the minimum-entropy model), ``registry`` (the methods by name: ``METHODS``, ``register_method``),
``per_profile`` (the per-group sharpening and the combination), ``estimate`` (``estimate_track_error`` and what every method shares), ``vibration`` (``fit_vibration``),
``options``; the track error itself is ``imaging.core.track_error``. Another method is one estimator
function and one ``register_method`` line (see ``registry``); it is then a choice wherever a method is
chosen. Every public name is importable from ``imaging.autofocus``. See docs/signal-model.md.
"""

from imaging.autofocus.estimate import (
    backproject_blocks,
    corrected_block,
    estimate_on_group_images,
    estimate_track_error,
    nothing_to_focus_on,
    select_pixels,
)
from imaging.autofocus.consistency import Consistency, consistency_of, split_band
from imaging.autofocus.options import DECISIONS, AutofocusOptions, AutofocusResult, ProfileBlock
from imaging.autofocus.per_profile import per_group_sharpening, residual_spectrum
from imaging.autofocus.pga import phase_gradient_autofocus
from imaging.autofocus.registry import METHODS, Estimator, register_method
from imaging.autofocus.subapertures import (
    TILE,
    GroupImages,
    assemble_group_images,
    entropy_and_gradient,
    group_images,
    image_entropy,
    resolution_m,
)
from imaging.autofocus.track_model import MODEL_PEAK_KEEP, evaluate_model, fit_track_model, minimum_entropy
from imaging.autofocus.vibration import VibrationFit, fit_vibration
from imaging.core.track_error import TrackError, remove_line

__all__ = [
    "DECISIONS", "METHODS", "MODEL_PEAK_KEEP", "TILE", "AutofocusOptions", "AutofocusResult", "Consistency",
    "Estimator", "GroupImages",
    "ProfileBlock", "TrackError", "VibrationFit", "assemble_group_images", "backproject_blocks",
    "consistency_of", "corrected_block", "entropy_and_gradient", "estimate_on_group_images", "estimate_track_error",
    "evaluate_model", "fit_track_model", "fit_vibration", "group_images", "image_entropy", "minimum_entropy",
    "nothing_to_focus_on", "per_group_sharpening", "phase_gradient_autofocus", "register_method", "remove_line", "residual_spectrum", "resolution_m",
    "select_pixels", "split_band",
]
