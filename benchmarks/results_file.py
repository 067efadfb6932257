"""The one way a benchmark writes its figures: ``docs/results/NAME.json``, strict JSON, with where and how
they were measured.

    from results_file import load_average, probe_machine, write_results
    started_load = load_average()
    probe_machine()                                # the VM's speed before (a speed benchmark's first step)
    ...                                            # the measurement
    write_results("stripmap", result, started_load=started_load)   # probes again: the speed after

Every number the README and the docs quote comes from one of these files (docs/results.md is generated from
them), so each records what reproduces it under ``"provenance"``: the git commit and whether the code differed
from it, the load average at the start and at the end (the machine is shared: a figure measured under load
says so), the CPU model and the command line. The benchmark's own keys are left as they are.

A benchmark that times things calls :func:`probe_machine` at its start; ``write_results`` then probes again
and records both as ``provenance.machine_speed = {"before": ..., "after": ...}``
(``benchmarks/machine_speed.py``: this VM's speed swings by up to 1.5x within an hour, so a speed figure says
which hour it ran in). A cheap accuracy-only benchmark does not call it and records no probe
(tests/test_results_file.py lists those that may not).

A NaN or an infinity is refused, naming where it is (``rows[3].error_db``), instead of being written as a
JSON that strict parsers reject or silently turned into ``null``: a figure that has no value (an image
compared with itself, a row not timed) is ``None`` where the benchmark makes it (:func:`finite_or_none`).
The refused result is kept in a temporary file the error names, so a long run is not lost.

Not a benchmark (``run_all.py`` skips it); scripts import it as ``results_file``, their own folder being
first on the import path.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path, PurePath
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from imaging.core import strict_json  # noqa: E402

#: The key the record of the run is written under, beside the benchmark's own keys.
PROVENANCE_KEY = "provenance"


def load_average() -> list[float]:
    """The machine's 1, 5 and 15 minute load averages (what to pass as ``started_load``)."""
    return [round(x, 2) for x in os.getloadavg()]


#: The probe :func:`probe_machine` took at the benchmark's start, for :func:`write_results` to record.
_probe_before: dict | None = None


def _machine_speed():
    """benchmarks/machine_speed.py, imported only where a benchmark probes (it loads numba and sarbot's
    kernel), from this folder whether or not it is on the import path."""
    here = str(Path(__file__).resolve().parent)
    if here not in sys.path:
        sys.path.append(here)
    import machine_speed  # noqa: PLC0415

    return machine_speed


def probe_machine() -> dict:
    """Probe the machine's speed now (``machine_speed.probe``, about 0.2 s of CPU) and keep it as the run's "before":
    a speed benchmark calls this at its start, before its measurement, and :func:`write_results` probes again
    after it and records both in the provenance.

    Returns
    -------
    dict
        The probe (``kernel_gbp_per_s``, ``fma_gflops``, ``copy_gb_per_s``, ...; see ``machine_speed.probe``).
    """
    global _probe_before
    machine_speed = _machine_speed()

    _probe_before = machine_speed.probe()
    return _probe_before


def _probe_after() -> dict | None:
    """``{"before": ..., "after": ...}`` where :func:`probe_machine` was called, with a new probe; else None."""
    if _probe_before is None:
        return None
    machine_speed = _machine_speed()
    return {"before": _probe_before, "after": machine_speed.probe()}


def finite_or_none(value: float) -> float | None:
    """``value`` as a float, or ``None`` where it is not a finite number (-inf dB for an image against itself):
    for a figure that legitimately has no value, said where the benchmark makes it."""
    value = float(value)
    return value if math.isfinite(value) else None


def non_numbers(obj: Any, path: str = "") -> list[str]:
    """The key paths in ``obj`` (``rows[3].error_db``, ``cube[0, 2]`` inside an array) whose value is NaN or
    infinite, in the order they come."""
    found: list[str] = []
    if isinstance(obj, (float, np.floating)):
        if not math.isfinite(obj):
            found.append(path or "(the value itself)")
    elif isinstance(obj, (complex, np.complexfloating)):
        if not (math.isfinite(obj.real) and math.isfinite(obj.imag)):
            found.append(path or "(the value itself)")
    elif isinstance(obj, dict):
        for key, value in obj.items():
            found += non_numbers(value, f"{path}.{key}" if path else str(key))
    elif isinstance(obj, (list, tuple)):
        for i, value in enumerate(obj):
            found += non_numbers(value, f"{path}[{i}]")
    elif isinstance(obj, np.ndarray) and obj.dtype.kind in "fc":
        found += [f"{path}[{', '.join(map(str, index))}]" for index in np.argwhere(~np.isfinite(obj))]
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        found += non_numbers(dataclasses.asdict(obj), path)
    return found


def _git(*args: str) -> str:
    run = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=60)
    return run.stdout.strip() if run.returncode == 0 else ""


def cpu_model() -> str:
    """The CPU's model name as the kernel reports it (``platform.processor()`` where /proc has none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance(started_load: list[float]) -> dict:
    """What reproduces a result: commit, whether the code differed from it, load at start and end, machine,
    command line."""
    # The results folder itself is left out of "dirty": a run that writes twice (a soak's checkpoints) or
    # after an earlier run has not changed the code it measures.
    changed = _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)docs/results")
    argv = list(sys.argv) or [""]
    script = Path(argv[0])
    if script.is_absolute() and script.is_relative_to(ROOT):
        argv[0] = str(script.relative_to(ROOT))
    return {"commit": _git("rev-parse", "HEAD") or "unknown", "tree_dirty": bool(changed),
            "load_average_start": [float(x) for x in started_load], "load_average_end": load_average(),
            "cpu_model": cpu_model(), "cpu_count": os.cpu_count(), "python": platform.python_version(),
            "command": shlex.join(["python", *argv]),
            "written_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def _raw(obj: Any) -> Any:
    """For the refused result's copy: what ``json`` cannot write by itself, NaN kept as NaN."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    if isinstance(obj, PurePath):
        return str(obj)
    return repr(obj)


def write_results(name: str, result: dict, *, started_load: list[float], folder: Path = RESULTS,
                  indent: int = 2, part: str | None = None) -> Path:
    """Write ``result`` to ``folder/NAME.json`` (docs/results by default) as strict JSON, with its provenance.

    Parameters
    ----------
    name
        The file's stem (``"stripmap"`` writes ``stripmap.json``).
    result
        The benchmark's figures; numpy values and dataclasses are written as plain JSON
        (:mod:`imaging.core.strict_json`). A result read back from an earlier file and written again (a soak
        summarised anew) keeps the run that measured it as ``provenance.measured_by``.
    started_load
        :func:`load_average` taken when the measurement started.
        Where :func:`probe_machine` was called, the machine is probed again here (about 0.2 s of CPU) and both
        probes are written as ``provenance.machine_speed``.
    folder
        Where to write; made if missing.
    indent
        JSON indentation (each benchmark keeps the one its committed file has).
    part
        Write ``result`` as this one key of the file, which keeps its other keys and their provenance
        (a benchmark that measures one part of another's results); the part carries its own provenance.

    Returns
    -------
    Path
        The file written. It is replaced atomically: a reader (or a run killed mid-write) sees the old file
        or the new one, never half of one.

    Raises
    ------
    ValueError
        If ``result`` holds a NaN or an infinity; the message names the key paths and the temporary file
        that keeps the refused result.
    """
    if not isinstance(result, dict):
        raise TypeError(f"write_results({name!r}): a result is a dict of figures, not a {type(result).__name__}")
    bad = non_numbers(result)
    if bad:
        with tempfile.NamedTemporaryFile("w", prefix=f"{name}.refused.", suffix=".json", delete=False) as kept:
            kept.write(json.dumps(result, default=_raw, indent=indent))
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        raise ValueError(f"{name}.json not written: not a number at {shown} (write None where a figure has no "
                         f"value); the result is kept in {kept.name}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.json"
    record = provenance(started_load)
    speed = _probe_after()
    if speed is not None:  # right after the load: the two conditions of the run a reader looks for together
        items = list(record.items())
        at = list(record).index("load_average_end") + 1
        record = dict(items[:at] + [("machine_speed", speed)] + items[at:])
    earlier = result.get(PROVENANCE_KEY)
    if isinstance(earlier, dict):
        record["measured_by"] = earlier.get("measured_by", earlier)
    whole = {**result, PROVENANCE_KEY: record}
    if part is not None:
        whole = {**(json.loads(path.read_text()) if path.exists() else {}), part: whole}
    text = strict_json.dumps(whole, indent=indent) + "\n"
    with tempfile.NamedTemporaryFile("w", dir=folder, prefix=f".{name}.", suffix=".tmp", delete=False) as tmp:
        tmp.write(text)
        tmp.flush()
        os.fsync(tmp.fileno())
    os.chmod(tmp.name, 0o644)  # NamedTemporaryFile makes it 0600; the results are for everyone to read
    os.replace(tmp.name, path)
    return path
