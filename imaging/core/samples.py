"""Raw ADC samples: int16 I/Q pairs (the wire's and the file's form) and complex64 (what the maths uses)."""

from __future__ import annotations

import numpy as np


def iq_to_complex(iq: np.ndarray) -> np.ndarray:
    """complex64 [...] from int16 I/Q pairs [..., 2]."""
    return (iq[..., 0].astype(np.float32) + 1j * iq[..., 1].astype(np.float32)).astype(np.complex64)


def complex_to_iq(samples: np.ndarray, counts_per_unit: float = 1.0) -> np.ndarray:
    """int16 I/Q pairs [..., 2] from complex samples scaled by ``counts_per_unit``, rounded and clipped
    as an ADC would."""
    iq = np.stack([samples.real, samples.imag], axis=-1) * counts_per_unit
    return np.clip(np.round(iq), -32768, 32767).astype(np.int16)
