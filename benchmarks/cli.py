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

__all__ = ["compare_rl", "evaluate", "reproduce_paper", "speed", "suite", "tune"]


def _run(module: str) -> int:
    importlib.import_module(f"benchmarks.{module}").main()
    return 0


def reproduce_paper() -> int:
    """``sdjls-reproduce-paper``: :func:`benchmarks.paper.reproduce.main`."""
    return _run("reproduce_paper")


def compare_rl() -> int:
    """``sdjls-compare-rl``: :func:`benchmarks.rl.compare.main`."""
    return _run("compare_rl")


def evaluate() -> int:
    """``sdjls-evaluate``: :func:`benchmarks.evaluate.main`."""
    return _run("evaluate")


def speed() -> int:
    """``sdjls-speed``: :func:`benchmarks.speed.main`."""
    return _run("speed")


def suite() -> int:
    """``sdjls-suite``: :func:`benchmarks.suite.main`."""
    return _run("suite")


def tune() -> int:
    """``sdjls-tune``: :func:`benchmarks.rl.tune.main`."""
    return _run("tune")
