"""SAR imaging: range compression, backprojection, the streaming strip map, image formation and metrics.

Sub-packages: ``imaging.core`` (what everything shares: errors, configuration, rig, waveform, trajectory,
geometry, windows, constants, samples, track error), ``imaging.io`` (the HDF5 file formats) and ``imaging.sim``
(simulators and scenes). Pure computation on arrays and dataclasses; the only I/O is reading and writing
the shared file formats. Nothing here opens a socket or starts a process.
"""

from imaging.jit_cache import key_jit_cache_to_sources as _key_jit_cache_to_sources

_key_jit_cache_to_sources()
