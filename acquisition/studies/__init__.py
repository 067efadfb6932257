"""Studies on simulated data and emulated hardware: ``reference_study`` (the reference robot-SAR study),
``autofocus_study`` (its limits again with autofocus), both run by ``paper`` (``sarbot experiment paper``),
``demo`` (the whole pipeline on a built-in scene), and ``map_feedback_live`` (the daemon with the map's
feedback on a replayed drive: tests/test_map_feedback_live.py and benchmarks/map_lag.py run it). No study
imports another: what they share is ``common``."""
