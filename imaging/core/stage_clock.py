"""Wall time of a computation's stages, summed per stage name: how ``sarbot image`` says where its time
goes (``sarbot -v image`` logs it; benchmarks/image_command.py reads it, see docs/cli.md).

A stage timed on one thread while another thread works (the next block's range compression beside the
backprojection) overlaps it: such stages are named for their thread, and only one thread's stages add up
to its wall time.
"""

from __future__ import annotations

import contextlib
import threading
import time


class StageClock:
    """Seconds per stage name, from ``time.perf_counter``; safe to use from several threads."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._lock = threading.Lock()

    def add(self, name: str, seconds: float) -> None:
        """Count ``seconds`` more for stage ``name``."""
        with self._lock:
            self.seconds[name] = self.seconds.get(name, 0.0) + seconds

    @contextlib.contextmanager
    def stage(self, name: str):
        """Time the block as stage ``name`` (added to what the stage had)."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - start)


@contextlib.contextmanager
def timed(clock: StageClock | None, name: str):
    """``clock.stage(name)``, or nothing where there is no clock."""
    if clock is None:
        yield
    else:
        with clock.stage(name):
            yield
