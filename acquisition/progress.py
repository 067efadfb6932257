"""Progress reporting for long work: a tqdm bar (with its ETA) on a terminal or in Jupyter, a log line every
10 % otherwise (a log file, systemd's journal), nothing with ``-q``."""

from __future__ import annotations

import logging
import os
import sys
import time

from .processes import VERBOSITY_ENV

log = logging.getLogger(f"sarbot.{__name__}")


def _in_notebook() -> bool:
    return "ipykernel" in sys.modules


class Progress:
    """Callable ``progress(done, total)`` for the compute functions' ``progress`` hooks.

    ``enabled`` None: on unless the command line said ``-q`` (verbosity -1, passed on in the environment).
    """

    def __init__(self, label: str, stream=None, enabled: bool | None = None, unit: str = "it"):
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = os.environ.get(VERBOSITY_ENV, "0") != "-1" if enabled is None else enabled
        self.bar_wanted = self.enabled and (_in_notebook() or (hasattr(self.stream, "isatty") and self.stream.isatty()))
        self.unit = unit
        self.start = time.monotonic()
        self._last_decile = -1
        self._bar = None

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        if self.bar_wanted:
            if self._bar is None:
                from tqdm.auto import tqdm

                self._bar = tqdm(total=total, desc=self.label, unit=self.unit, file=self.stream, leave=True,
                                 dynamic_ncols=True)
            self._bar.total = total
            self._bar.update(min(done, total) - self._bar.n)
            if done >= total:
                self.close()
            return
        frac = min(done / total, 1.0)
        decile = int(frac * 10)
        if decile != self._last_decile:
            self._last_decile = decile
            log.info("%s: %d/%d (%.0f%%) after %.1f s", self.label, done, total, 100 * frac, time.monotonic() - self.start)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
