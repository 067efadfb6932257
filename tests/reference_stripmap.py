"""What the strip map's "ffbp" blocks image, by the direct kernel profile by profile: the reference its FFBP
is checked against (tests/test_stripmap.py) and measured against (benchmarks/stripmap_ffbp.py)."""

from __future__ import annotations

import dataclasses

import numpy as np

from imaging.backprojection import backproject
from imaging.stripmap import StripMap


def block_reference(config, radar, tx_order, frames, trajectory) -> StripMap:
    """The map of ``frames`` [(adc, frame time ns)] in blocks of ``config.ffbp_block_frames`` consecutive
    frames, each block backprojected by the direct kernel onto the pixels of its footprint (the block's
    mean phase centre and look), as ``StripMap`` with ``algorithm="ffbp"`` decides them."""
    ref = StripMap(dataclasses.replace(config, algorithm="direct"))
    b = config.ffbp_block_frames
    for start in range(0, len(frames), b):
        block = [ref.frame_profiles(radar, tx_order, adc, t, trajectory) for adc, t in frames[start:start + b]]
        tx, rx = np.concatenate([f[1] for f in block]), np.concatenate([f[2] for f in block])
        look = np.concatenate([f[3] for f in block]).mean(axis=0)
        touched, masks, _ = ref._footprint((0.5 * (tx + rx)).mean(axis=0)[:2], look / np.linalg.norm(look))
        for key, mask in zip(touched, masks):
            x, y = ref.tile_points(key)
            iy, ix = np.nonzero(mask)
            pts = np.stack([x[ix], y[iy], np.full(iy.size, config.z_m)], axis=1)
            values = np.zeros(iy.size, np.complex128)
            for profiles, tx_m, rx_m, _, _ in block:
                backproject(profiles, tx_m, rx_m, pts, mode=config.mode, out=values)
            ref._tile(key)[iy, ix] += values
    return ref
