"""SAR imaging core: waveform and rig, simulator, range compression, backprojection, metrics.

Pure computation on arrays and dataclasses; the only I/O is reading and writing the shared HDF5 file
formats (``imaging.recording``, ``imaging.imagefile``). Nothing here opens a socket or starts a process.
"""

SPEED_OF_LIGHT_MPS = 299_792_458.0
