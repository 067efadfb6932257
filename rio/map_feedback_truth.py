"""The map's velocity measurements (``rio.map_feedback``) against the truth, where the truth is known (a
simulated drive, a replayed simulation): is each measurement's sigma honest?

A measurement says "the trajectory's velocity along d was off by e +- sigma over this span". Its true value
is the slope, over the span, of the trajectory's position error along d (truth minus trajectory): the map was
imaged on the trajectory's positions, so that is the error its tiles can see (``true_velocity_error_mps``).
What a refocus that found the track error exactly would have read (``exact_tiles``: the track errors the
trajectory's actual position and attitude errors give each tile's groups, fitted as the map's are) splits a
measurement's error in two: the refocus's own (measured minus exact) and the model's (exact minus true: a
trajectory error that is not one constant velocity error over the span, which the tiles still see, such as
the filter's cross-track velocity wandering during the span). The normalised errors
((measured - true) / sigma)^2 average to 1 (NEES) where the sigmas are honest.

Pure computation: used by benchmarks/map_feedback_sigma.py and tests/test_map_feedback.py.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from imaging.core.track_error import TrackError, remove_line

from .map_feedback import LookVelocityMeasurement, MapFeedbackConfig, velocity_error_from_tiles

#: The exact track errors are fitted whatever they explain and however weakly: the aim is what the map's
#: model makes of the true error, not whether the map would have sent it.
EXACT_FIT = MapFeedbackConfig(max_sigma_mps=np.inf, min_explained=-np.inf)


#: The sigma before the nuisances were counted (the fit's residual scatter only), to compare on the same tiles.
RESIDUAL_ONLY = MapFeedbackConfig(track_accel_sigma_mps2=0.0, refocus_bend_m=0.0, max_sigma_mps=0.01)


@dataclasses.dataclass(frozen=True)
class MeasurementTruth:
    """One map measurement and its truth (m/s along its direction): ``measured`` +- ``sigma``, ``true`` (the
    trajectory's position error's slope over the span), ``exact`` (what a perfect refocus would have read:
    the same fit to the track errors the trajectory's actual errors give), and the filter's speed along it."""

    measurement: LookVelocityMeasurement
    measured_mps: float
    sigma_mps: float
    true_mps: float
    exact_mps: float

    @property
    def normalised_error(self) -> float:
        """(measured - true) / sigma: standard normal where the sigma is honest."""
        return (self.measured_mps - self.true_mps) / self.sigma_mps


def true_velocity_error_mps(measurement: LookVelocityMeasurement, truth, trajectory, samples: int = 64) -> float:
    """The slope over the measurement's span of (truth - trajectory) position along its direction (m/s)."""
    half_ns = 0.5 * measurement.span_s * 1e9
    t_ns = np.round(measurement.time_ns + np.linspace(-half_ns, half_ns, samples)).astype(np.int64)
    error = (truth.sample(t_ns).position_m - trajectory.sample(t_ns).position_m) @ np.asarray(measurement.direction, float)
    t_s = (t_ns - measurement.time_ns) * 1e-9
    return float(np.polyfit(t_s, error, 1)[0])


def exact_tiles(tiles, truth, trajectory) -> list:
    """``tiles`` (pairs of track error and ``ScattererGeometry``) with each track error replaced by the one the
    trajectory's actual error gives: each group's antenna where the truth had it (the truth's pose, the
    antenna's offset from the trajectory's pose turned by the attitude error), its range to the scatterer
    shorter by that much, read along the tile's direction, line removed (``imaging.core.track_error``)."""
    out = []
    for te, geo in tiles:
        t_ns = geo.time_origin_ns + np.round(np.asarray(geo.time_s) * 1e9).astype(np.int64)
        on_traj, on_truth = trajectory.sample(t_ns), truth.sample(t_ns)
        attitude_error = np.einsum("nij,nkj->nik", on_truth.rotation_matrix, on_traj.rotation_matrix)
        offset = geo.antenna_m - on_traj.position_m
        true_antenna = on_truth.position_m + np.einsum("nij,nj->ni", attitude_error, offset)
        to_scatterer = geo.scatterer_m[None, :] - geo.antenna_m
        shorter = np.linalg.norm(to_scatterer, axis=1) - np.linalg.norm(geo.scatterer_m[None, :] - true_antenna, axis=1)
        c = np.sum(geo.direction * to_scatterer, axis=1) / np.linalg.norm(to_scatterer, axis=1)
        exact = TrackError(np.asarray(geo.time_s, float), remove_line(geo.time_s, shorter / c), "exact", None,
                           geo.time_origin_ns)
        out.append((exact, geo))
    return out


def measurement_truths(tile_sets, truth, trajectory, config: MapFeedbackConfig | None = None,
                       each_tile: bool = False) -> list[MeasurementTruth]:
    """Each measurement of ``tile_sets`` (pairs (tiles, measurements read off them), as
    ``rio.feedback_drive.LoopResult.tile_sets``) against the truth; ``trajectory`` is the one the map was
    imaged on. With ``config`` the measurements are read off the tiles again with it (the same values,
    other sigmas); with ``each_tile`` every tile alone (as the live map, which refocuses each radar's tiles
    in a call of its own)."""
    out = []
    for tiles, measurements in tile_sets:
        for group in ([[tile] for tile in tiles] if each_tile else [tiles]):
            if config is not None or each_tile:
                measurements = velocity_error_from_tiles(group, config or MapFeedbackConfig())
            if not measurements:
                continue
            exact = velocity_error_from_tiles(exact_tiles(group, truth, trajectory), EXACT_FIT)
            for m in measurements:
                # the exact fit's estimate along this measurement's direction (its basis may differ in sign)
                along = [e.velocity_error_mps * float(np.dot(e.direction, m.direction)) for e in exact
                         if abs(float(np.dot(e.direction, m.direction))) > 0.99]
                out.append(MeasurementTruth(m, m.velocity_error_mps, m.sigma_mps,
                                            true_velocity_error_mps(m, truth, trajectory),
                                            along[0] if along else float("nan")))
    return out


def nees(truths: list[MeasurementTruth]) -> float:
    """The mean squared normalised error of ``truths``: 1 where the sigmas are honest (NaN for none)."""
    return float(np.mean([t.normalised_error ** 2 for t in truths])) if truths else float("nan")


def position_error_accel_rms_mps2(truth, trajectory, start_ns: int, end_ns: int, span_s: float = 1.5,
                                  step_s: float = 0.25) -> np.ndarray:
    """The RMS acceleration [3] (world x, y, z) of the trajectory's position error (truth minus trajectory)
    over windows of ``span_s`` from ``start_ns`` to ``end_ns``: a parabola fitted per window and axis. What
    ``MapFeedbackConfig.track_accel_sigma_mps2`` models (a bend of the track error a tile cannot tell from a
    velocity error)."""
    accels = []
    for t0 in np.arange(start_ns, end_ns - span_s * 1e9, step_s * 1e9):
        t_ns = np.round(t0 + np.linspace(0.0, span_s * 1e9, 64)).astype(np.int64)
        error = truth.sample(t_ns).position_m - trajectory.sample(t_ns).position_m
        t_s = (t_ns - t_ns.mean()) * 1e-9
        accels.append([2.0 * np.polyfit(t_s, error[:, i], 2)[0] for i in range(3)])
    return np.sqrt(np.mean(np.square(accels), axis=0)) if accels else np.full(3, np.nan)


def sigma_honesty(tile_sets, truth, trajectory) -> dict:
    """NEES and counts of the measurements ``tile_sets`` give, with the sigma now and with the residual's
    alone (``RESIDUAL_ONLY``), the tiles of a set jointly and each tile alone: {model: {fit: {...}}}."""
    out = {}
    for name, config in (("now", MapFeedbackConfig()), ("residual_only", RESIDUAL_ONLY)):
        for each_tile in (False, True):
            truths = measurement_truths(tile_sets, truth, trajectory, config, each_tile)
            out.setdefault(name, {})["each_tile" if each_tile else "joint"] = {
                "measurements": len(truths), "nees": nees(truths),
                "normalised_errors": [t.normalised_error for t in truths],
                "error_mps": [t.measured_mps - t.true_mps for t in truths], "sigma_mps": [t.sigma_mps for t in truths]}
    return out
