"""Studies on simulated data and emulated hardware: ``paper`` (the reference robot-SAR study) and ``demo``
(the whole pipeline on a built-in scene)."""
