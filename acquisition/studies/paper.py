"""``sarbot experiment paper``: the reference robot-SAR measurement study reproduced on simulated data
(studies 1-6, ``acquisition.studies.reference_study``) and its limits again with autofocus (study 7,
``acquisition.studies.autofocus_study``), into ``report.json``, ``report.md`` and their figures.

This module only runs the studies and puts their reports together; what they share is
``acquisition.studies.common``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from imaging.core import strict_json

from ..progress import Progress
from .autofocus_study import AutofocusStudy
from .autofocus_study import markdown as autofocus_markdown
from .reference_study import ReferenceStudy, markdown_lines


def run_paper(out_dir: Path, quick: bool = False) -> dict:
    """Run studies 1-7 (``quick``: fewer apertures and runs) and write their report into ``out_dir``."""
    t0 = time.monotonic()
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="sarbot-paper-") as tmp:
        p = ReferenceStudy(out_dir, Path(tmp), quick)
        bar = Progress("experiment")
        steps = ["simulating the passes", "range profiles", "cross-range width", "vibration", "integration gain",
                 "on the RIO trajectory", "where methods fail", "with autofocus"]
        report: dict = {"quick": quick}

        def step(k):
            bar(k, len(steps))
            print(f"sarbot experiment paper: {k + 1}/{len(steps)} {steps[k]}", flush=True)

        step(0)
        passes = p.passes()
        step(1)
        report["range"] = p.range_profiles(passes)
        step(2)
        report["cross_range"] = p.cross_range(passes, autofocus=True)
        step(3)
        report["vibration"] = p.vibration()
        step(4)
        report["integration_gain"] = p.integration_gain(report["vibration"])
        step(5)
        report["rio"] = p.rio()
        step(6)
        report["failure"] = p.failure(passes)
        step(7)
        report["autofocus"] = AutofocusStudy(p).run(report["failure"])
        bar(len(steps), len(steps))
    report["elapsed_s"] = time.monotonic() - t0
    (out_dir / "report.json").write_text(strict_json.dumps(report, indent=2))
    (out_dir / "report.md").write_text(markdown(report))
    return report


def markdown(r: dict) -> str:
    """``report.md``: sections 1-6, then study 7 where it ran."""
    lines = markdown_lines(r)
    if "autofocus" in r:
        lines += [""] + autofocus_markdown(r["autofocus"])
    return "\n".join(lines) + "\n"
