"""The console commands of ``pyproject.toml``'s ``[project.scripts]``.

A console command runs ``sys.exit(function())``: a ``main`` that returns its result (a ``Score``,
a summary dict) would make the command print that object and exit with status 1. Each function
here runs one script's ``main`` on the command line's arguments and returns 0; argparse's own
exits (``--help``: 0, a bad option: 2) pass through.

* ``sdjls-reproduce-paper``: ``python -m benchmarks.reproduce_paper``;
* ``sdjls-compare-rl``: ``python -m benchmarks.compare_rl``;
* ``sdjls-evaluate``: ``python -m benchmarks.evaluate``;
* ``sdjls-speed``: ``python -m benchmarks.speed``;
* ``sdjls-suite``: ``python -m benchmarks.suite``;
* ``sdjls-tune``: ``python -m benchmarks.tune``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from benchmarks.core.commands import COMMANDS

__all__ = ["compare_rl", "evaluate", "reproduce_paper", "speed", "suite", "tune"]


def _command(script: str, target: str) -> Callable[[], int]:
    """The console command of ``script``: runs ``target``'s ``main`` and returns 0."""

    def run() -> int:
        importlib.import_module(f"benchmarks.{script}").main()
        return 0

    run.__name__ = run.__qualname__ = script
    run.__doc__ = f"``{COMMANDS[script]}``: :func:`{target}.main`."
    return run


reproduce_paper = _command("reproduce_paper", "benchmarks.paper.reproduce")
compare_rl = _command("compare_rl", "benchmarks.rl.compare")
evaluate = _command("evaluate", "benchmarks.evaluate")
speed = _command("speed", "benchmarks.speed")
suite = _command("suite", "benchmarks.suite")
tune = _command("tune", "benchmarks.rl.tune")
