"""The house rules a newcomer relies on: no import circles, dependencies that flow one way, rooms of a
readable size, a Layout section that matches the folders, and a README that stands on its own."""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("acquisition", "drivers", "rio", "imaging")
PURE = ("imaging", "rio")  # pure computation: never imports the I/O side
MAX_MODULE_LINES = 600


def _tracked(*patterns: str) -> list[Path]:
    out = subprocess.run(["git", "ls-files", "-z", "--", *patterns], cwd=ROOT, capture_output=True, check=True)
    return [ROOT / p for p in out.stdout.decode().split("\0") if p and (ROOT / p).is_file()]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imported(module: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The project's modules that ``module`` imports anywhere in its text (at the top or inside a function:
    an import put off until it is needed still ties the two modules together), except under
    ``if TYPE_CHECKING:``, which only annotations see."""
    names = []
    tree = ast.parse(path.read_text(), str(path))
    type_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If) and _is_type_checking(block.test)
                 for stmt in block.body for n in ast.walk(stmt)}
    for node in ast.walk(tree):
        if id(node) in type_only:  # annotations only: never imported when the program runs
            continue
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = module.split(".")[: None if path.name == "__init__.py" else -1]
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([base] if base else []))
            names += [base] + [f"{base}.{a.name}" for a in node.names]
    found = set()
    for name in names:
        while name and name not in known:
            name = name.rpartition(".")[0]
        if name and name != module and not module.startswith(name + "."):  # a parent package is imported anyway
            found.add(name)
    return found


def _import_graph() -> dict[str, set[str]]:
    known = _modules()
    return {m: _imported(m, p, known) for m, p in known.items()}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, stack, on_stack, found, counter = {}, {}, [], set(), [], 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def test_the_circle_finder_finds_a_circle():
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _circles({"a": {"b"}, "b": set()}) == []


def test_no_module_imports_itself_round_a_circle():
    assert _circles(_import_graph()) == []


def test_pure_computation_imports_nothing_of_the_io_side():
    wrong = {m: sorted(d for d in deps if d.split(".")[0] not in PURE)
             for m, deps in _import_graph().items() if m.split(".")[0] in PURE}
    assert {m: d for m, d in wrong.items() if d} == {}


def test_no_module_outside_the_tests_is_over_600_lines():
    long = {str(p.relative_to(ROOT)): n for p in _tracked("*.py")
            if not p.relative_to(ROOT).parts[0] == "tests" and (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert long == {}


def _layout_folders(readme: str) -> set[str]:
    """The folders the README's Layout section names: a fenced block whose lines start with a folder (``name/``);
    an indented folder lies inside the last folder above it that is indented less."""
    section = re.search(r"^## Layout\n(.*?)(?=^## |\Z)", readme, re.S | re.M)
    assert section, "the README has no '## Layout' section"
    block = re.search(r"```[^\n]*\n(.*?)```", section.group(1), re.S)
    assert block, "the Layout section has no fenced block"
    folders, parents = set(), []  # parents: (indent, path)
    for line in block.group(1).splitlines():
        m = re.match(r"^( *)([\w.-]+(?:/[\w.-]+)*/)(?:\s|$)", line)
        if not m:
            continue
        indent, name = len(m.group(1)), m.group(2)
        while parents and parents[-1][0] >= indent:
            parents.pop()
        path = (parents[-1][1] if parents else "") + name
        folders.add(path.rstrip("/"))
        parents.append((indent, path))
    return folders


def test_the_layout_parser_nests_indented_folders():
    text = "## Layout\n```\nacquisition/   the daemon\n  cli/         commands\n  workers/\ndrivers/\n  radar/\n```\n"
    assert _layout_folders(text) == {"acquisition", "acquisition/cli", "acquisition/workers", "drivers",
                                     "drivers/radar"}


def test_every_folder_of_the_layout_exists_and_every_package_folder_is_in_it():
    folders = _layout_folders((ROOT / "README.md").read_text())
    assert sorted(f for f in folders if not (ROOT / f).is_dir()) == []
    packages = {str(p.parent.relative_to(ROOT)) for p in _tracked("*/__init__.py")}
    assert sorted(packages - folders) == []
    assert {"systemd", "tests", "docs", "benchmarks"} <= folders


def test_the_readme_is_a_newcomer_s_page_that_stands_on_its_own():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.encode()) <= 12288
    assert "../" not in readme and "shared/" not in readme
    for path in re.findall(r"\]\(([^)#\s]+)", readme):  # every relative link reaches a file of the repository
        if not re.match(r"[a-z]+:", path):
            assert (ROOT / path).exists(), path


def test_nothing_outside_the_tests_points_outside_the_repository():
    """The contracts are the repository's own docs; only tests may read beside the checkout, and the peers
    benchmark builds the real torchbp from the shared sources (``../shared/bench``), never a dependency. The
    changelog keeps its history as it was written."""
    texts = {".py", ".md", ".toml", ".yml", ".service", ".target", ".cfg", ".msg", ".txt"}
    outside = re.compile(r"DESIGN\.md|\.\./shared(?!/bench)")
    pointing = {str(p.relative_to(ROOT)): m.group(0) for p in _tracked()
                if p.relative_to(ROOT).parts[0] not in ("tests", ".ci") and p.name != "CHANGELOG.md"
                and p.suffix in texts and (m := outside.search(p.read_text(errors="replace")))}
    assert pointing == {}
