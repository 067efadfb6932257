"""Raw ADC samples: int16 I/Q pairs (the wire's and the file's form) and complex64 (what the maths uses)."""

from __future__ import annotations

import numpy as np


def iq_to_complex(iq: np.ndarray) -> np.ndarray:
    """complex64 [...] from int16 I/Q pairs [..., 2]."""
    if iq.shape[-1:] != (2,):
        raise ValueError(f"I/Q samples need a last axis of 2 (I, Q); got shape {iq.shape}")
    # complex64 is two float32 side by side: one conversion pass, then a view (ten times faster than
    # building real + 1j * imag, and it runs on every frame).
    return np.ascontiguousarray(iq, dtype=np.float32).view(np.complex64)[..., 0]


def complex_to_iq(samples: np.ndarray, counts_per_unit: float = 1.0) -> np.ndarray:
    """int16 I/Q pairs [..., 2] from complex samples scaled by ``counts_per_unit``, rounded and clipped
    as an ADC would."""
    iq = np.stack([samples.real, samples.imag], axis=-1) * counts_per_unit
    return np.clip(np.round(iq), -32768, 32767).astype(np.int16)
