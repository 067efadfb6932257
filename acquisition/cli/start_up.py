"""A command's start-up with Python's cyclic garbage collector paused.

Importing numpy, scipy, h5py and numba and building numba's registries makes about 120,000 objects that
live as long as the process. The collector, run by allocation counts, goes through all of them again and
again while they are made (in a new ``sarbot image`` process: 3 full and 20-odd middle-generation
collections, and one more at exit) and finds nothing to free (benchmarks/image_command.py: ``process_start``,
the start-up with the collector running and paused). :func:`collector_paused` pauses it for the start-up
and then freezes what the start-up made (``gc.freeze``: moved where collections do not look), so later
collections, at exit too, go through only what the command itself makes.
"""

from __future__ import annotations

import contextlib
import gc


@contextlib.contextmanager
def collector_paused():
    """Run the block (imports, set-up) with the cyclic garbage collector paused, then freeze what exists.

    Reference counting still frees everything that is not in a cycle; only cycles made inside the block
    stay until the process ends, and start-up makes few.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if was_enabled:
            gc.enable()
