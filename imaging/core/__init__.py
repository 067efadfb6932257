"""What every part of sarbot shares: errors, configuration, the rig and waveform, trajectories, antenna
geometry, windows, image grids, physical constants, the int16 I/Q sample form and the track error.

Light on purpose: numpy and scipy only (no h5py, no matplotlib), because the driver processes import it.
"""
