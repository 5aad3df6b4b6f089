"""The reader of a ``benchmarks.rl.tune`` study summary (``<out>/<study>.json``).

:func:`read_summary` is the one reader of that file for :mod:`benchmarks.rl.compare`
(``--tuned``) and :mod:`benchmarks.rl.tuned_report`: it checks what they rely on (the tuned task,
algorithm and variant, the budget the study tuned at, a best trial) and names the file when
something is missing. It is re-exported by :mod:`benchmarks.rl.tune`, which writes the file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["read_summary"]


def read_summary(path: str | Path) -> tuple[tuple[str, str, str], tuple[tuple[str, Any], ...],
                                            dict[str, Any]]:  # fmt: skip
    """``((task, algo, variant), overrides, summary)`` of a ``<out>/<study>.json`` written by
    :func:`benchmarks.rl.tune.main`: the best trial's overrides as sorted ``(name, value)`` pairs
    (:attr:`benchmarks.rl.train.RunSpec.overrides`). A ValueError names a file that is not a
    summary, whose ``settings.timesteps`` (the budget it tuned at) is not a positive int, or
    whose study has no complete trial."""
    try:
        data = json.loads(Path(path).read_text())
        settings, best = data["settings"], data["best"]
        key = (str(settings["task"]), str(settings["algo"]), str(settings["variant"]))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a benchmarks.rl.tune summary ({exc!r})") from None
    steps = settings.get("timesteps")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"{path}: settings.timesteps = {steps!r}; expected the study's budget, "
                         "a positive integer")  # fmt: skip
    if best is None or not isinstance(best.get("overrides"), dict):
        raise ValueError(f"{path}: the study has no complete trial")
    return key, tuple(sorted(best["overrides"].items())), data
