"""Every command the README and the site's pages show exists, with the options they show.

The commands are read from the Markdown (inline code and code blocks): each ``python -m
benchmarks.X ...`` and ``sdjls-X ...`` is run with ``--help`` (in this process: a script's
``main`` with ``--help`` prints its usage and exits 0), and every ``--option`` the documentation
gives it must be among the options the help lists. A console command's usage line names the
console command (``usage: sdjls-evaluate``), not the module.
"""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest

from benchmarks.core.commands import COMMANDS

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SCRIPT = re.compile(r"(?:python -m benchmarks\.(\w+)|\b(sdjls-[a-z-]+))((?:[^`\n]|\\\n)*)")
BY_COMMAND = {command: script for script, command in COMMANDS.items()}


def _documented() -> dict[str, set[str]]:
    """Each documented script, and the options the pages give it."""
    found: dict[str, set[str]] = {}
    for page in PAGES:
        text = page.read_text(encoding="utf-8").replace("\\\n", " ")
        for spans in (
            re.findall(r"`([^`\n]+)`", text),
            re.findall(r"```bash\n(.*?)```", text, re.S),
        ):
            for span in spans:
                for module, command, rest in SCRIPT.findall(span):
                    script = module or BY_COMMAND.get(command)
                    if script is None:
                        continue  # a name such as sdjls-gym, not a command
                    options = set(re.findall(r"(?<![\w-])(--[a-z][\w-]*)", rest))
                    found.setdefault(script, set()).update(options)
    return found


DOCUMENTED = _documented()


def _help(script: str, argv0: str, monkeypatch, capsys) -> str:
    module = importlib.import_module(f"benchmarks.{script}")
    monkeypatch.setattr(sys, "argv", [argv0, "--help"])
    with pytest.raises(SystemExit) as exc:
        module.main(["--help"])
    assert exc.value.code == 0
    return capsys.readouterr().out


def test_the_pages_document_every_console_command():
    assert set(COMMANDS) <= set(DOCUMENTED), sorted(set(COMMANDS) - set(DOCUMENTED))


@pytest.mark.parametrize("script", sorted(DOCUMENTED))
def test_each_documented_command_takes_the_options_the_pages_give_it(script, monkeypatch, capsys):
    text = _help(script, f"benchmarks/{script}.py", monkeypatch, capsys)
    assert text.startswith(f"usage: python -m benchmarks.{script}")
    listed = set(re.findall(r"(?<![\w-])(--[a-z][\w-]*)", text))
    assert DOCUMENTED[script] <= listed, sorted(DOCUMENTED[script] - listed)


@pytest.mark.parametrize("script", sorted(COMMANDS))
def test_a_console_commands_usage_names_the_command(script, monkeypatch, capsys):
    command = COMMANDS[script]
    text = _help(script, f"/venv/bin/{command}", monkeypatch, capsys)
    assert text.startswith(f"usage: {command} "), text.splitlines()[0]
