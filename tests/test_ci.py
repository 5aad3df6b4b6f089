"""CI runs what the README says: its test command, lint and the docstring examples, and the
pre-commit configuration runs the same checks."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

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
    assert "mypy sdjls_gym controllers benchmarks" in ci_lines  # issue 32: typed end to end
    assert any("--doctest-modules sdjls_gym controllers" in line for line in ci_lines)


def test_pre_commit_runs_the_same_checks():
    config = (ROOT / ".pre-commit-config.yaml").read_text(encoding="utf-8")
    for entry in (
        "entry: ruff check",
        "entry: ruff format --check",
        "entry: mypy sdjls_gym controllers benchmarks",
        "--doctest-modules sdjls_gym controllers",
    ):
        assert entry in config, entry


def _ci_commands() -> list[str]:
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    return [line.strip() for line in ci.splitlines() if line.strip() and not line.startswith("#")]


def test_ci_builds_a_fresh_virtualenv_before_any_check():
    """A green CI must mean the README's commands work on a fresh machine: .ci/run removes its
    old virtualenv, makes a new one and activates it before it installs or checks anything."""
    lines = _ci_commands()
    first_install = next(i for i, line in enumerate(lines) if line.startswith("pip install"))
    remove = next(i for i, line in enumerate(lines) if line.startswith("rm -rf .ci/venv"))
    make = next(i for i, line in enumerate(lines) if "-m venv .ci/venv" in line)
    activate = next(i for i, line in enumerate(lines) if line == ". .ci/venv/bin/activate")
    checks = [
        i for i, line in enumerate(lines) if line.startswith(("ruff", "mypy", "python -m pytest"))
    ]
    assert remove < make < activate < first_install < min(checks)
    assert "--system-site-packages" not in " ".join(lines)


def test_ci_virtualenv_and_zoo_logs_are_ignored():
    """The virtualenv of .ci/run and rl_zoo3's default logs/ are neither committed, nor linted,
    nor collected."""
    for path in (".ci/venv/bin/python", "logs/ppo/run/x.zip"):
        out = subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT, check=False)
        assert out.returncode == 0, f"{path} is not ignored by .gitignore"
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert ".ci/venv" in config["tool"]["ruff"]["extend-exclude"]
    pytest_ini = config["tool"]["pytest"]["ini_options"]
    assert pytest_ini["testpaths"] == ["tests"] and ".*" in pytest_ini["norecursedirs"]


def _requirement_bounds(requirement: str) -> tuple[str, str | None]:
    """``(name, upper bound or None)`` of a PEP 508 requirement string."""
    name = re.match(r"[A-Za-z0-9_.-]+", requirement).group(0)
    upper = re.search(r"<\s*([0-9][0-9.]*)", requirement)
    return name.lower().replace("_", "-"), None if upper is None else upper.group(1)


def test_extras_are_bounded_below_the_next_breaking_release():
    """pytest 9 refused what pytest 8 accepted (approx of a list of dicts): every tool of the dev
    extra, and every package of an extra, is bounded above; ruff by its minor release (its
    rules change there); torch stays a range that the CPU build on disk (2.13.0) satisfies."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    extras = config["project"]["optional-dependencies"]
    for extra, requirements in extras.items():
        for requirement in requirements:
            name, upper = _requirement_bounds(requirement)
            assert upper is not None, f"{extra}: {requirement} has no upper bound"
            if name == "ruff":
                assert upper.count(".") == 1 and upper.startswith("0."), requirement
            if name == "torch":
                assert requirement.replace(" ", "") == "torch>=2.3,<2.14", requirement
    dev = {_requirement_bounds(r)[0] for r in extras["dev"]}
    assert {"pytest", "hypothesis", "ruff", "mypy", "stable-baselines3", "ray", "rl-zoo3"} <= dev


def test_readme_test_times_say_what_was_measured():
    """The Quickstart's test times are measurements (seconds, test counts, the machine's load),
    not "a few minutes" / "under two minutes" (issue 28: they took 14-15 and almost 4 minutes)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = re.search(r"^## Quickstart\n(.*?)(?=^## )", readme, flags=re.M | re.S).group(1)
    text = " ".join(section.split())
    assert "a few minutes" not in text and "under two minutes" not in text
    assert re.search(r"\d+ s for `python -m pytest -q -n 2` \(\d+ tests\)", text)
    assert re.search(r'`python -m pytest -q -n 2 -m "not slow"` took \d+ s \(\d+ tests', text)
    assert "load average" in text
