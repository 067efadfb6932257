"""Write docs/results.md, the results page, from the measured figures in docs/results/*.json.

    python3 dev.py results                 # what the project runs
    python docs/gen_results.py [--output PATH] [--results DIR]

The page is generated, never edited by hand: each benchmark or evaluation gets a section that says what it
measures, the command that reproduces it, its chart where there is one, and tables of its figures read from
its JSON (scalars as a figure/value table, lists of rows as tables). A JSON file without an entry in
``SECTIONS`` still gets a section, so a new benchmark shows up at once. The output depends on the JSON files
only (no dates, no machine), so tests/test_docs.py can regenerate it and compare.

Only the standard library: this runs before anything is installed.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from results_sections import SECTIONS  # the page's sections, beside this file (run as a script or imported from docs/)

DOCS = Path(__file__).resolve().parent
RESULTS = DOCS / "results"
OUTPUT = DOCS / "results.md"

#: Longest list of rows tabulated; longer ones (time series of the soaks) are only counted.
MAX_ROWS = 40
#: Most columns of a table of rows (the rest are in the JSON).
MAX_COLUMNS = 12
#: Longest string shown in a cell.
MAX_TEXT = 90



def fmt(value) -> str:
    """A value for a table cell: floats to 4 significant digits, long text cut, lists inline if short."""
    if value is None:  # strict JSON's null: a number that was NaN or infinite
        return "n/a"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value) or math.isinf(value):
            return str(value)
        return f"{value:.4g}"
    if isinstance(value, list):
        if len(value) <= 6 and all(not isinstance(v, (list, dict)) for v in value):
            return "[" + ", ".join(fmt(v) for v in value) + "]"
        return f"({len(value)} values)"
    if isinstance(value, dict):
        return f"({len(value)} entries)"
    text = str(value).replace("|", "/").replace("\n", " ")
    return text if len(text) <= MAX_TEXT else text[:MAX_TEXT - 3] + "..."


def _is_scalar(value) -> bool:
    return not isinstance(value, (dict, list)) or isinstance(value, list) and len(value) <= 6 and all(
        not isinstance(v, (list, dict)) for v in value)


def machine_speed_text(probe) -> str:
    """One probe of benchmarks/machine_speed.py (a provenance's ``machine_speed.before`` or ``.after``) as a cell:
    its three speeds and when it was taken."""
    if not isinstance(probe, dict):
        return fmt(probe)
    parts = []
    for key, unit, label in (("kernel_gbp_per_s", "G bp/s", "kernel"), ("fma_gflops", "GFLOP/s", "FMA"),
                             ("copy_gb_per_s", "GB/s", "copy")):
        if isinstance(probe.get(key), (int, float)):
            parts.append(f"{label} {probe[key]:.3g} {unit}")
    if isinstance(probe.get("widest_vectors"), str):
        parts.append(probe["widest_vectors"])
    if isinstance(probe.get("utc"), str):
        parts.append(f"at {probe['utc'][11:19]} UTC")
    return ", ".join(parts) if parts else fmt(probe)


def _figures(data: dict, prefix: str = "", depth: int = 0) -> list[tuple[str, str]]:
    """Scalars of ``data`` as (dotted name, value), nested dicts to depth 2; a provenance's machine-speed probes
    (before and after the run) as one row each, beside its load."""
    out = []
    for key, value in data.items():
        name = f"{prefix}{key}"
        if key == "machine_speed" and prefix.endswith("provenance.") and isinstance(value, dict):
            out += [(f"{name}.{side}", machine_speed_text(value[side])) for side in ("before", "after") if side in value]
        elif _is_scalar(value):
            out.append((name, fmt(value)))
        elif isinstance(value, dict) and depth < 2:
            out += _figures(value, f"{name}.", depth + 1)
    return out


def _row_tables(data: dict, prefix: str = "", depth: int = 0) -> list[tuple[str, list]]:
    """Lists of rows (dicts) in ``data``, with their dotted names."""
    out = []
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            out.append((name, value))
        elif isinstance(value, dict) and depth < 2:
            out += _row_tables(value, f"{name}.", depth + 1)
    return out


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def _rows_table(rows: list[dict]) -> list[str]:
    columns: list[str] = []
    for row in rows:
        for key, value in row.items():
            if key not in columns and _is_scalar(value):
                columns.append(key)
    nested = sorted({k for row in rows for k, v in row.items() if not _is_scalar(v)})
    shown = columns[:MAX_COLUMNS]
    lines = _table(shown, [[fmt(row[c]) if c in row else "" for c in shown] for row in rows])
    left = columns[MAX_COLUMNS:] + nested
    if left:
        lines += ["", f"Also in the JSON per row: {', '.join(f'`{c}`' for c in left)}."]
    return lines


def section(stem: str, data, results_dir: Path) -> list[str]:
    title, what, command = SECTIONS.get(stem, (stem, "", f"python3 dev.py bench (writes {stem}.json)"))
    lines = [f"## {title}", ""]
    if what:
        lines += [what, ""]
    lines += [f"Reproduce: `{command}` (source: [`results/{stem}.json`](results/{stem}.json)).", ""]
    if (results_dir / f"{stem}.png").exists():
        lines += [f"![{title}](results/{stem}.png)", ""]
    elif "/" in stem:  # an evaluation with a folder of its own: every chart in it, linked
        folder = stem.rsplit("/", 1)[0]
        charts = sorted(p.name for p in (results_dir / folder).glob("*.png"))
        if charts:
            lines += ["Charts: " + ", ".join(f"[{c[:-4]}](results/{folder}/{c})" for c in charts) + ".", ""]
    if not isinstance(data, dict):
        return lines + [f"(a JSON {type(data).__name__}, not tabulated)", ""]
    figures = _figures(data)
    if figures:
        lines += _table(["figure", "value"], [[f"`{n}`", v] for n, v in figures]) + [""]
    for name, rows in _row_tables(data):
        lines += [f"**`{name}`**", ""]
        if len(rows) > MAX_ROWS:
            lines += [f"{len(rows)} rows (a series over the run; see the JSON and the chart).", ""]
        else:
            lines += _rows_table(rows) + [""]
    return lines


def render(results_dir: Path = RESULTS) -> str:
    stems = sorted(p.stem for p in results_dir.glob("*.json"))
    stems += sorted(f"{p.parent.name}/report" for p in results_dir.glob("*/report.json"))
    ordered = [s for s in SECTIONS if s in stems] + [s for s in stems if s not in SECTIONS]
    lines = ["# Results", "",
             "<!-- Generated by `python3 dev.py results` (docs/gen_results.py) from docs/results/*.json: "
             "do not edit by hand. -->", "",
             "Every figure sarbot's documentation quotes, as measured by the benchmarks (`python3 dev.py bench` "
             "runs them all; `--quick` makes each a smoke run) on the project's 2-core development machine. Each "
             "benchmark reports ratios against a baseline run in the same process, so a slower machine changes the "
             "absolute numbers, not the comparisons. The reference study on simulated data is "
             "[its own report](results/paper/report.md) (`sarbot experiment paper`). What the numbers mean and "
             "how they came about: [benchmark notes](benchmark-notes.md).", "",
             "Contents: " + ", ".join(f"[{SECTIONS.get(s, (s,))[0]}](#{_anchor(SECTIONS.get(s, (s,))[0])})"
                                      for s in ordered), ""]
    for stem in ordered:
        data = json.loads((results_dir / f"{stem}.json").read_text())
        lines += section(stem, data, results_dir)
    return "\n".join(lines).rstrip() + "\n"


def _anchor(title: str) -> str:
    """The heading's id as MkDocs (Python-Markdown's toc) makes it."""
    text = "".join(ch for ch in title.lower() if ch.isalnum() or ch in " -_")
    return "-".join(text.split())


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--output", type=Path, default=OUTPUT, help="the page to write (default docs/results.md)")
    ap.add_argument("--results", type=Path, default=RESULTS, help="where the JSON files are (default docs/results)")
    args = ap.parse_args(argv)
    args.output.write_text(render(args.results))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
