"""The ``sarbot`` command's entry point: the command line, or one line saying which of sarbot's top-level
packages another distribution has put in its place.

sarbot installs four top-level packages (``acquisition``, ``drivers``, ``rio``, ``imaging``). Names that
plain invite a clash: ``pip install drivers`` or ``pip install rio`` writes another project's files over
sarbot's (or a folder on ``PYTHONPATH`` shadows them), and the next command failed with an ImportError deep
in a traceback. This module imports nothing of sarbot until it has to, and on an ImportError asks the
installed distributions' metadata (their RECORD of files) who owns what Python would import under each
name; where that is a distribution other than sarbot, it says so in one line and exits with code 2.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

#: sarbot's top-level packages (pyproject.toml's packages.find).
TOP_LEVEL_PACKAGES = ("acquisition", "drivers", "rio", "imaging")
DISTRIBUTION = "sarbot"
EXIT_USAGE = 2


def _normalized(name: str) -> str:
    return name.lower().replace("_", "-").replace(".", "-")


def _import_location(name: str) -> Path | None:
    """The file or folder Python imports (or imported) as ``name``, without importing it."""
    module = sys.modules.get(name)
    spec = module.__spec__ if module is not None and module.__spec__ is not None else None
    if spec is None:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            return None
    if spec is None:
        return None
    if spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations))).resolve()
    return Path(spec.origin).resolve() if spec.origin else None


def foreign_packages() -> list[tuple[str, Path, str, str]]:
    """sarbot's top-level packages that Python imports from another distribution's files:
    (package, where it is imported from, that distribution's name and version)."""
    from importlib import metadata

    owners = metadata.packages_distributions()
    found = []
    for package in TOP_LEVEL_PACKAGES:
        location = _import_location(package)
        if location is None:
            continue
        for owner in dict.fromkeys(owners.get(package, [])):
            if _normalized(owner) == DISTRIBUTION:
                continue
            try:
                dist = metadata.distribution(owner)
            except metadata.PackageNotFoundError:
                continue
            for record in dist.files or []:
                path = Path(dist.locate_file(record)).resolve()
                if path == location or location in path.parents:
                    found.append((package, location, dist.metadata["Name"] or owner, dist.version))
                    break
            else:
                continue
            break
    return found


def explain(found: list[tuple[str, Path, str, str]]) -> str:
    """One line: which packages are not sarbot's, whose they are, and the way out."""
    parts = [f"'{package}' at {location} is {name} {version}'s" for package, location, name, version in found]
    names = " ".join(dict.fromkeys(name for _, _, name, _ in found))
    return (f"sarbot: error: another distribution has put its own package in place of sarbot's: {'; '.join(parts)} "
            f"(pip uninstall {names}, then pip install --force-reinstall --no-deps sarbot; or use a virtual "
            f"environment of its own)")


def main(argv: list[str] | None = None) -> int:
    """``sarbot``: run the command line; an ImportError that another distribution's package explains ends
    in that one line (exit 2), any other goes on as it is."""
    try:
        from acquisition.cli import end_process, main as cli_main

        code = cli_main(argv)
    except ImportError:
        found = foreign_packages()
        if not found:
            raise
        print(explain(found), file=sys.stderr)
        return EXIT_USAGE
    # Run as the process's command (the ``sarbot`` script): it may end here at once (acquisition.cli.end_process).
    return end_process(code) if argv is None else code


if __name__ == "__main__":
    sys.exit(main())
