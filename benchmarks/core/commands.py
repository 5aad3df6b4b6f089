"""The console commands of the scripts, and the name a script's usage line shows."""

from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["COMMANDS", "SCRIPTS", "prog"]

#: Each script's console command (``pyproject.toml``'s ``[project.scripts]``).
COMMANDS: dict[str, str] = {
    "compare_rl": "sdjls-compare-rl",
    "evaluate": "sdjls-evaluate",
    "reproduce_paper": "sdjls-reproduce-paper",
    "speed": "sdjls-speed",
    "suite": "sdjls-suite",
    "tune": "sdjls-tune",
}

#: Each script (``python -m benchmarks.<script>``) and the module that implements it.
SCRIPTS: dict[str, str] = {
    "compare_rl": "benchmarks.rl.compare",
    "evaluate": "benchmarks.evaluate",
    "render_picture": "benchmarks.pictures.render",
    "reproduce_paper": "benchmarks.paper.reproduce",
    "speed": "benchmarks.speed.measure",
    "suite": "benchmarks.suite.cli",
    "tree_picture": "benchmarks.pictures.tree",
    "tune": "benchmarks.rl.tune",
    "tuned_report": "benchmarks.rl.tuned_report",
}


def prog(script: str) -> str:
    """The program name of ``script``'s usage line: its console command when it runs as one
    (``sdjls-evaluate``), else ``python -m benchmarks.<script>``."""
    command = COMMANDS.get(script)
    if command is not None and Path(sys.argv[0]).name == command:
        return command
    return f"python -m benchmarks.{script}"
