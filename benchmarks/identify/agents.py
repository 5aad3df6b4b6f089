"""The agents' learning curves, read from the suite comparison's committed summary.

``results/rl_suite/summary.json`` (``python -m benchmarks.compare_rl``) holds, for each task and
each kept run, its learning curve (``learning_curve``: a point every tenth of the budget, the
first at 0 steps, each scored on 100 episodes) and the gap of each point to the task's one-step
RHC curve in % (``learning_curve_gaps``, None where the point diverged or left the curve's range
of risk), and the run's final score on the evaluation episodes (``score.curve_gap``). A wing may
read another wing's committed results; nothing here imports it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks.core.cli import COMMITTED_RESULTS

__all__ = ["DEFAULT_AGENTS", "AgentCurve", "configs", "read_agents"]

#: Where the agents' learning curves are read from.
DEFAULT_AGENTS = COMMITTED_RESULTS / "rl_suite" / "summary.json"


@dataclass(frozen=True)
class AgentCurve:
    """One agent run's learning curve on one task.

    Attributes
    ----------
    env_id, config : str
        The task and the configuration (``"ppo_lagrangian"``).
    seed : int
    steps : tuple of int
        Training env steps of each point (the first 0: the untrained policy).
    gaps : tuple of float or None
        Each point's gap to the one-step RHC curve, % of its cost.
    final_gap : float or None
        The trained run's gap on the evaluation episodes (the paired gap of the protocol).
    final_reason : str or None
        Why it has none.
    """

    env_id: str
    config: str
    seed: int
    steps: tuple[int, ...]
    gaps: tuple[float | None, ...]
    final_gap: float | None
    final_reason: str | None


def _curve(env_id: str, run: Mapping[str, Any]) -> AgentCurve:
    score = run.get("score") or {}
    gap = score.get("curve_gap")
    return AgentCurve(
        env_id=env_id,
        config=f"{run['algo']}_{run['variant']}",
        seed=int(run["seed"]),
        steps=tuple(int(p["timesteps"]) for p in run["learning_curve"]),
        gaps=tuple(None if g is None else float(g) for g in run["learning_curve_gaps"]),
        final_gap=None if gap is None or gap.get("relative") is None else float(gap["relative"]),
        final_reason=run.get("curve_gap_reason"),
    )


def read_agents(path: str | Path = DEFAULT_AGENTS) -> dict[str, list[AgentCurve]]:
    """``{env_id: [AgentCurve, ...]}`` from a suite comparison's ``summary.json``; ``{}`` when
    the file does not exist.

    Raises
    ------
    ValueError
        The file is not a suite comparison's summary (a key or a field missing), named.
    """
    path = Path(path)
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return {env_id: [_curve(env_id, run) for run in task["rl_runs"]]
                for env_id, task in data["tasks"].items()}  # fmt: skip
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(
            f"{path} is not a suite comparison's summary.json (python -m benchmarks.compare_rl): "
            f"{type(exc).__name__} {exc}"
        ) from None


def configs(curves: list[AgentCurve]) -> dict[str, list[AgentCurve]]:
    """The curves by configuration, in their first appearance's order, each sorted by seed."""
    out: dict[str, list[AgentCurve]] = {}
    for c in curves:
        out.setdefault(c.config, []).append(c)
    return {k: sorted(v, key=lambda c: c.seed) for k, v in out.items()}
