"""Run every benchmark; each writes its figures to docs/results/."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: Scripts here that are not benchmarks: this one, and what the benchmarks import.
#: peers.py runs in its own environment (dev.py bench --peers); image_command.py runs command_versions.py;
#: machine_speed.py is the probe every benchmark takes (its --watch is run by hand, for minutes).
NOT_BENCHMARKS = {"run_all.py", "process_stats.py", "results_file.py", "peers.py", "command_versions.py",
                  "machine_speed.py"}


def main(argv: list[str]) -> int:
    failed = 0
    for script in sorted(HERE.glob("*.py")):
        if script.name in NOT_BENCHMARKS:
            continue
        print(f"== {script.name}", flush=True)
        failed += subprocess.run([sys.executable, str(script), *argv]).returncode != 0
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
