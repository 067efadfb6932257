"""Studies on simulated data and emulated hardware: ``reference_study`` (the reference robot-SAR study),
``autofocus_study`` (its limits again with autofocus), both run by ``paper`` (``sarbot experiment paper``),
and ``demo`` (the whole pipeline on a built-in scene). No study imports another: what they share is
``common``."""
