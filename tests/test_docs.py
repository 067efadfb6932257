"""The documentation in the repository: the generated results page is current, the site builds with
--strict, the Python tutorial runs, and the README stays a newcomer's page."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

#: The pages the code's docstrings cite, and the ones the README links to.
PAGES = ["architecture.md", "conventions.md", "signal-model.md", "formats/recording.md", "formats/trajectory.md",
         "formats/image.md", "wire/srf1.md", "wire/dca1000.md", "wire/xbus.md", "wire/can.md", "bus.md", "export.md",
         "live-view.md", "config/rig.md", "config/scene.md", "cli.md", "results.md"]


def test_results_page_is_what_the_generator_makes_of_the_committed_json(tmp_path):
    out = tmp_path / "results.md"
    run = subprocess.run([sys.executable, str(DOCS / "gen_results.py"), "--output", str(out)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert out.read_text() == (DOCS / "results.md").read_text(), \
        "docs/results.md is out of date: run `python3 dev.py results` and commit it"


def test_results_page_has_a_section_with_its_command_for_every_json():
    page = (DOCS / "results.md").read_text()
    stems = sorted(p.stem for p in (DOCS / "results").glob("*.json"))
    stems += [f"{p.parent.name}/report" for p in (DOCS / "results").glob("*/report.json")]  # the paper study
    assert "paper/report" in stems
    for stem in stems:
        assert f"(results/{stem}.json)" in page
    assert page.count("Reproduce: `") == len(stems)
    # A figure from the JSON, as the table shows it: the default backprojection mode's SER to the exact filter.
    assert "| `default_mode.ser_db` | 67.78 |" in page  # issue 34's kernel: 67.78 dB (was 67.79)


def test_results_generator_tabulates_scalars_and_rows(tmp_path):
    sys.path.insert(0, str(DOCS))
    try:
        import gen_results
    finally:
        sys.path.remove(str(DOCS))
    (tmp_path / "toy.json").write_text('{"speed_mps": 0.123456, "case": {"frames": 8}, '
                                       '"rows": [{"mode": "a", "db": -40.04}, {"mode": "b", "db": -3.0}]}')
    page = gen_results.render(tmp_path)
    assert "| `speed_mps` | 0.1235 |" in page
    assert "| `case.frames` | 8 |" in page
    assert "| mode | db |" in page and "| a | -40.04 |" in page and "| b | -3 |" in page
    assert "Reproduce: `python3 dev.py bench" in page


def test_results_commands_name_scripts_that_exist():
    """The results page says how to reproduce each section: the benchmark scripts it names are there."""
    sys.path.insert(0, str(DOCS))
    try:
        import gen_results
    finally:
        sys.path.remove(str(DOCS))
    scripts = {s for _, _, command in gen_results.SECTIONS.values() for s in re.findall(r"benchmarks/\w+\.py", command)}
    assert scripts
    missing = sorted(s for s in scripts if not (ROOT / s).is_file())
    assert not missing, f"docs/gen_results.py names scripts that are gone: {missing}"


def test_the_pages_the_code_cites_exist():
    for page in PAGES:
        assert (DOCS / page).is_file(), page
    cited = set()
    for path in [*ROOT.glob("acquisition/**/*.py"), *ROOT.glob("drivers/**/*.py"), *ROOT.glob("rio/*.py"),
                 *ROOT.glob("imaging/**/*.py"), *ROOT.glob("imaging/**/*.toml"), *ROOT.glob("tests/*.py")]:
        cited |= set(re.findall(r"docs/([\w/-]+\.md)", path.read_text()))
    assert cited, "no docstring cites a page"
    missing = sorted(p for p in cited if not (DOCS / p).is_file())
    assert not missing, f"cited but not written: {missing}"


def test_no_docstring_cites_a_file_outside_the_repository():
    offenders = [str(p.relative_to(ROOT)) for p in [*ROOT.glob("acquisition/**/*.py"), *ROOT.glob("drivers/**/*.py"),
                                                    *ROOT.glob("rio/*.py"), *ROOT.glob("imaging/**/*.py"),
                                                    *ROOT.glob("imaging/**/*.toml")]
                 if "DESIGN.md" in p.read_text()]
    assert not offenders


#: The console script of the environment the tests run in (the command a user types).
SARBOT = str(Path(sys.executable).parent / "sarbot")


def _python_blocks(page: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", page.read_text(), flags=re.S | re.M)


def test_python_api_tutorial_runs(tmp_path, monkeypatch):
    """Every python block of the notebook tutorial, in order, in one namespace (its asserts included)."""
    blocks = _python_blocks(DOCS / "tutorials" / "python-api.md")
    assert len(blocks) >= 5
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "tutorial"}
    for k, block in enumerate(blocks):
        exec(compile(block, f"python-api.md block {k + 1}", "exec"), namespace)
    # What the tutorial measured, checked here too: the target where it was put, widths as theory says.
    a = namespace["a"]
    assert a["peak_m"][1] == pytest.approx(2.0, abs=0.004)
    assert a["cross_range"]["half_power_width_m"] == pytest.approx(namespace["theory_x"], rel=0.1)


def test_tutorial_commands_are_real_sarbot_commands():
    """Every `sarbot COMMAND` in a tutorial's shell blocks is a command of the CLI, and its long options are
    options of that command (checked against `sarbot COMMAND --help`)."""
    helps: dict[str, str] = {}
    for page in sorted((DOCS / "tutorials").glob("*.md")):
        for block in re.findall(r"^```(?:bash|sh|console)\n(.*?)^```", page.read_text(), flags=re.S | re.M):
            text = block.replace("\\\n", " ")
            for line in text.splitlines():
                line = line.split("#", 1)[0]
                for m in re.finditer(r"\bsarbot ([a-z][a-z0-9-]*)((?:\s+(?!\||&&|;)[^\s|;&]+)*)", line):
                    command, args = m.group(1), re.sub(r"'[^']*'|\"[^\"]*\"", "", m.group(2))  # not quoted values
                    if command not in helps:
                        run = subprocess.run([SARBOT, command, "--help"], capture_output=True, text=True, cwd=ROOT,
                                             timeout=60)
                        assert run.returncode == 0, f"{page.name}: `sarbot {command}` is not a command: {run.stderr}"
                        helps[command] = run.stdout
                    for option in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", args):
                        assert option in helps[command], f"{page.name}: `sarbot {command}` has no option {option}"
    assert helps, "no sarbot command found in the tutorials"


def test_readme_is_a_newcomers_page():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.encode()) <= 12288
    first_block = re.search(r"^```\w*\n(.*?)^```", readme, flags=re.S | re.M).group(1)
    assert first_block.splitlines() == [
        "python3 dev.py demo    # first use creates .venv and installs sarbot; then runs the whole pipeline on emulated hardware",
        "python3 dev.py test    # the test suite, exactly as CI runs it (.ci/run)"]
    assert "../" not in readme and "DESIGN.md" not in readme and "/work/" not in readme
    for link in re.findall(r"\]\(([^)#]+)", readme):
        if not link.startswith("http"):
            assert (ROOT / link).exists(), f"README links to {link}, which is not in the repository"


def test_docs_site_builds_strict(tmp_path):
    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip("mkdocs is not installed (pip install -e .[docs]); the site build is not checked")
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                         cwd=ROOT, capture_output=True, text=True, timeout=600,
                         env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert run.returncode == 0, run.stderr[-5000:]
    assert (tmp_path / "site" / "index.html").is_file()
    api = (tmp_path / "site" / "api" / "imaging" / "index.html").read_text()
    assert "range_compress" in api and "backproject" in api
