"""The README's tables are copies of the committed benchmark reports, not numbers typed by hand.

The README copies the claims table of ``results/paper/REPORT.md``, the results table of
``results/rl/REPORT.md``, the speed tables of ``results/speed/SPEED.md`` and the steps table of
``results/identify/REPORT.md``. When a benchmark is re-run and its report changes, this test
fails until the README is updated from it.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import COPIED_TABLES, section, uncopied_rows

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


@pytest.mark.parametrize(("title", "report", "min_rows"), [t[:3] for t in COPIED_TABLES])
def test_readme_tables_are_copied_from_the_committed_reports(title, report, min_rows):
    missing = uncopied_rows(README, title, ROOT / report, min_rows)
    assert not missing, f"README rows not in {report} (re-copy them from it): {missing[:3]}"


def test_readme_names_the_commands_and_shows_the_figures():
    for command in (
        "python -m benchmarks.reproduce_paper",
        "python -m benchmarks.compare_rl",
        "python -m benchmarks.speed",
        "python -m benchmarks.identify",
    ):
        assert command in README
    for figure in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", README):
        assert (ROOT / figure).is_file(), f"README shows {figure}, which does not exist"


PYTHON_BLOCKS = re.findall(r"```python\n(.*?)```", README, flags=re.S)


@pytest.mark.parametrize("index", range(len(PYTHON_BLOCKS)))
def test_readme_python_examples_run(index, tmp_path, monkeypatch, capsys):
    """Every ```python block of the README runs as written (in a scratch folder)."""
    monkeypatch.chdir(tmp_path)
    exec(compile(PYTHON_BLOCKS[index], f"README.md python block {index}", "exec"), {})
    if "PAPER_K[info[" in PYTHON_BLOCKS[index]:  # the environment example prints what it says
        assert capsys.readouterr().out.split() == ["20", "20.0", "-731.2"]
    if "ScenarioTreeController(" in PYTHON_BLOCKS[index]:  # so does the controllers' example
        assert capsys.readouterr().out.split() == ["solved", "True", "13"]


def test_readme_is_short_and_wrapped():
    """A README a newcomer reads in five minutes (the manual is the site in docs/): at most 240
    lines (each study one short section: the paper, the suite, RL, learn-then-control, the mode
    hidden, speed), prose wrapped at 100 characters (tables and code excepted)."""
    lines, in_code, long = README.splitlines(), False, []
    for number, line in enumerate(lines, 1):
        if line.startswith("```"):
            in_code = not in_code
        elif not in_code and not line.startswith("|") and len(line) > 100:
            long.append(number)
    assert len(lines) <= 240 and not long, (len(lines), long)


def _conclusions(report: str) -> list[str]:
    """The bullet sentences of a report's "## Conclusions" section, whitespace folded."""
    text = section((ROOT / report).read_text(encoding="utf-8"), "Conclusions")
    return [" ".join(b.split()) for b in re.findall(r"^- (.*?)(?=^- |\Z)", text,
                                                     flags=re.M | re.S)]  # fmt: skip


def test_the_readmes_conclusions_are_the_reports_own_sentences():
    """The conclusions the README states about the RL comparisons are copied from the reports,
    where code writes them from the numbers (benchmarks/rl/claims.py): a sentence typed by hand,
    or left over from an earlier scoring, fails here."""
    rl = section(README, "Receding horizon against reinforcement learning")
    match = re.search(r"^Conclusions[^\n]*:\n\n(.*?)(?=\n\n[^-]|\Z)", rl, flags=re.M | re.S)
    assert match, "README's RL section has no 'Conclusions ...:' list"
    bullets = [" ".join(b.split()) for b in re.findall(r"^- (.*?)(?=^- |\Z)", match.group(1),
                                                       flags=re.M | re.S)]  # fmt: skip
    reports = _conclusions("results/rl/REPORT.md") + _conclusions("results/rl_suite/REPORT.md")
    assert bullets and all(b in reports for b in bullets), [b for b in bullets if b not in reports]
