"""The console commands of the scripts, and the name a script's usage line shows."""

from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["COMMANDS", "prog"]

#: Each script's console command (``pyproject.toml``'s ``[project.scripts]``).
COMMANDS: dict[str, str] = {
    "compare_rl": "sdjls-compare-rl",
    "evaluate": "sdjls-evaluate",
    "reproduce_paper": "sdjls-reproduce-paper",
    "speed": "sdjls-speed",
    "suite": "sdjls-suite",
    "tune": "sdjls-tune",
}


def prog(script: str) -> str:
    """The program name of ``script``'s usage line: its console command when it runs as one
    (``sdjls-evaluate``), else ``python -m benchmarks.<script>``."""
    command = COMMANDS.get(script)
    if command is not None and Path(sys.argv[0]).name == command:
        return command
    return f"python -m benchmarks.{script}"
