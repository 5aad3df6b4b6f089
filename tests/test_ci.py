"""CI runs what the README says: its test command, lint and the docstring examples, and the
pre-commit configuration runs the same checks."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _quickstart_commands() -> list[str]:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = re.search(r"^## Quickstart\n(.*?)(?=^## )", readme, flags=re.M | re.S).group(1)
    return re.findall(r"```bash\n(.*?)\n```", section, flags=re.S)


def test_ci_runs_the_readmes_test_command_lint_and_doctests():
    commands = _quickstart_commands()
    assert len(commands) == 2, commands  # install and run the main job; install and run tests
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    ci_lines = [line.strip() for line in ci.splitlines()]
    assert commands[1].strip() in ci_lines  # the README's test command, verbatim
    assert "ruff check ." in ci_lines and "ruff format --check ." in ci_lines
    assert any("--doctest-modules sdjls_gym controllers" in line for line in ci_lines)


def test_pre_commit_runs_the_same_checks():
    config = (ROOT / ".pre-commit-config.yaml").read_text(encoding="utf-8")
    for entry in (
        "entry: ruff check",
        "entry: ruff format --check",
        "--doctest-modules sdjls_gym controllers",
    ):
        assert entry in config, entry
