"""Progress reporting for long work: a bar on a terminal, a log line every 10 % otherwise."""

from __future__ import annotations

import logging
import sys
import time

log = logging.getLogger(f"sarbot.{__name__}")


class Progress:
    """Callable ``progress(done, total)`` for the compute functions' ``progress`` hooks."""

    def __init__(self, label: str, stream=None, enabled: bool = True):
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.start = time.monotonic()
        self._last_decile = -1

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        frac = min(done / total, 1.0)
        elapsed = time.monotonic() - self.start
        if self.tty:
            width = 30
            fill = int(round(frac * width))
            self.stream.write(f"\r{self.label:<12} [{'#' * fill}{'.' * (width - fill)}] {done}/{total} {elapsed:5.1f}s")
            if done >= total:
                self.stream.write("\n")
            self.stream.flush()
        else:
            decile = int(frac * 10)
            if decile != self._last_decile:
                self._last_decile = decile
                log.info("%s: %d/%d (%.0f%%) after %.1f s", self.label, done, total, 100 * frac, elapsed)
