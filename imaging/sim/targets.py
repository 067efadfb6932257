"""Scatterers of a simulated scene, each reduced to a scattering centre per (TX, RX) pair.

Modelled no further than the imaging needs: a point, a thin vertical metal rod whose scattering centre
stays on the cylinder surface facing the radar, and a trihedral corner reflector whose phase centre is its
apex and whose return falls off away from its axis.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from imaging.core.errors import ConfigError


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@dataclasses.dataclass(frozen=True)
class PointTarget:
    """An isotropic point of complex amplitude ``amplitude * exp(j phase_deg)``."""

    position_m: tuple[float, float, float]
    amplitude: float = 1.0
    phase_deg: float = 0.0

    def scattering_centres(self, tx_m: np.ndarray, rx_m: np.ndarray):
        """Centre positions [P, n_rx, 3] and complex amplitudes [P, n_rx] for chirps with TX at tx_m [P,3], RX rx_m [P,n_rx,3]."""
        pos = np.broadcast_to(np.asarray(self.position_m, float), rx_m.shape).copy()
        amp = np.full(rx_m.shape[:2], self.amplitude * np.exp(1j * math.radians(self.phase_deg)), complex)
        return pos, amp


@dataclasses.dataclass(frozen=True)
class Rod:
    """A thin vertical metal cylinder: axis through ``position_m`` (x, y), from ``z_min_m`` to ``z_max_m``.

    Its specular point lies on the surface towards the midpoint of TX and RX, at their mean height
    (clamped to the rod), so the imaged position sits ``radius_m`` in front of the axis.
    """

    position_m: tuple[float, float]
    radius_m: float = 0.005
    z_min_m: float = 0.0
    z_max_m: float = 1.0
    amplitude: float = 1.0
    phase_deg: float = 180.0  # a conductor reflects with a sign flip

    def __post_init__(self) -> None:
        if self.radius_m < 0:
            raise ConfigError("radius_m", f"must not be negative, got {self.radius_m}")
        if self.z_max_m <= self.z_min_m:
            raise ConfigError("z_max_m", f"must exceed z_min_m ({self.z_min_m}), got {self.z_max_m}")

    def scattering_centres(self, tx_m: np.ndarray, rx_m: np.ndarray):
        mid = 0.5 * (tx_m[:, None, :] + rx_m)  # [P, n_rx, 3]
        axis = np.array([self.position_m[0], self.position_m[1]], float)
        toward = _unit(mid[..., :2] - axis)
        pos = np.empty_like(mid)
        pos[..., :2] = axis + self.radius_m * toward
        pos[..., 2] = np.clip(mid[..., 2], self.z_min_m, self.z_max_m)
        amp = np.full(mid.shape[:2], self.amplitude * np.exp(1j * math.radians(self.phase_deg)), complex)
        return pos, amp


@dataclasses.dataclass(frozen=True)
class CornerReflector:
    """A trihedral corner reflector: phase centre at the apex, gain falling off away from its axis.

    ``axis`` points from the apex out of the reflector's opening (towards where it looks). The two-way
    amplitude pattern is Gaussian with half-power at ``half_power_angle_deg`` off the axis (a triangular
    trihedral's RCS stays within 3 dB over roughly +-20 deg).
    """

    position_m: tuple[float, float, float]
    axis: tuple[float, float, float] = (0.0, -1.0, 0.0)
    amplitude: float = 3.0
    phase_deg: float = 0.0
    half_power_angle_deg: float = 20.0

    def __post_init__(self) -> None:
        if np.linalg.norm(self.axis) == 0:
            raise ConfigError("axis", "must not be the zero vector")
        if not 0 < self.half_power_angle_deg <= 90:
            raise ConfigError("half_power_angle_deg", f"must be in (0, 90], got {self.half_power_angle_deg}")

    def scattering_centres(self, tx_m: np.ndarray, rx_m: np.ndarray):
        apex = np.asarray(self.position_m, float)
        pos = np.broadcast_to(apex, rx_m.shape).copy()
        look = _unit(0.5 * (tx_m[:, None, :] + rx_m) - apex)
        cos_angle = np.clip(look @ _unit(np.asarray(self.axis, float)), -1.0, 1.0)
        angle = np.degrees(np.arccos(cos_angle))
        # Amplitude pattern: power halves at the stated angle; nothing from behind the reflector.
        gain = np.where(cos_angle > 0, 10 ** (-0.15 * (angle / self.half_power_angle_deg) ** 2), 0.0)
        amp = gain * self.amplitude * np.exp(1j * math.radians(self.phase_deg))
        return pos, amp


TARGET_KINDS = {"point": PointTarget, "rod": Rod, "corner": CornerReflector}
