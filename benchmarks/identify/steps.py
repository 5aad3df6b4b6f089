"""The budgets of the learning curve, and the rule that reads off the steps a learner needs.

**The grid** (:func:`step_grid`): whole episodes of the task's horizon ``T``: the 1-2-5 sequence
(1, 2, 5, 10, 20, ... episodes) from the fewest that :func:`controllers.identify` can accept
(:func:`~benchmarks.identify.learner.min_episodes`) up to the largest agent budget of the task,
together with every budget at which an agent of the suite comparison has a learning-curve point
(:func:`agent_budgets`: ``j B / 10`` for ``j = 1..10`` of each configuration's budget ``B``,
rounded down to whole episodes), so that the learner is scored at the agents' own budgets.

**Within 5%** (:func:`steps_within`): a learning curve is within 5% of the true-model
controller at a budget where its gap to the reference curve at equal risk is at most
:data:`WITHIN` percent (a cheaper policy, a negative gap, is within; a point without a gap, one
that diverged or left the curve's range of risk, is not). ``rule="kept"`` (the one the report
leads with) takes the first budget from which every later point of the curve is within;
``rule="first"`` the first budget that is within. Across seeds (:func:`across_seeds`): the
median over the seeds, a seed that never gets within counting as never (so the median is a
number when at least half of the seeds, 3 of 5, get within), with the fewest and most steps of
the seeds that do.

>>> steps_within([100, 200, 500, 1000], [12.0, 3.0, 7.0, 1.0])
1000
>>> steps_within([100, 200, 500, 1000], [12.0, 3.0, 7.0, 1.0], rule="first")
200
>>> across_seeds([200, 100, None, 1000, 500])
{'median': 500, 'low': 100, 'high': 1000, 'within': 4, 'seeds': 5}
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

from benchmarks.identify.learner import min_episodes
from sdjls_gym.systems import TASKS, Task
from sdjls_gym.validation import check_choice

__all__ = [
    "AGENT_CURVE_POINTS",
    "RULES",
    "WITHIN",
    "across_seeds",
    "agent_budgets",
    "step_grid",
    "steps_within",
]

#: A learning curve is within at a point whose gap is at most this many percent.
WITHIN = 5.0
#: The agents' learning curves: a point every tenth of the budget (results/rl_suite's runs,
#: ``benchmarks.rl``'s learning-curve setting), after the untrained policy at 0 steps.
AGENT_CURVE_POINTS = 10
#: The rules of :func:`steps_within`.
RULES = ("kept", "first")


def agent_budgets(env_id: str) -> dict[str, int]:
    """Each suite configuration's budget (env steps) on the task: ``{"ppo_reward": 600000, ...}``
    (``benchmarks.rl``'s :data:`SUITE_CONFIGS` and :func:`suite_timesteps`)."""
    from benchmarks.rl import SUITE_CONFIGS, suite_timesteps

    return {f"{a}_{v}": int(suite_timesteps(env_id, a, v)) for a, v in SUITE_CONFIGS}


def _one_two_five(low: int, high: int) -> list[int]:
    """The 1-2-5 sequence within ``[low, high]``."""
    out, decade = [], 1
    while decade <= high:
        out += [c * decade for c in (1, 2, 5) if low <= c * decade <= high]
        decade *= 10
    return out


def step_grid(task: Task | str, budgets: Iterable[int],
              points: int = AGENT_CURVE_POINTS) -> tuple[int, ...]:  # fmt: skip
    """The learning curve's budgets (env steps, increasing) on ``task`` for agent budgets
    ``budgets`` (see the module docstring): whole episodes, from :func:`min_episodes` up to the
    largest budget, with each budget's ``points`` learning-curve points."""
    t = task if isinstance(task, Task) else TASKS[check_choice("task", task, tuple(TASKS))]
    T, first = t.horizon, min_episodes(t)
    budgets = [int(b) for b in budgets]
    largest = max(budgets, default=first * T) // T
    episodes = set(_one_two_five(first, max(largest, first)))
    for b in budgets:
        episodes.update(j * b // points // T for j in range(1, points + 1))
    return tuple(e * T for e in sorted(episodes) if e >= first)


def steps_within(steps: Sequence[int], gaps: Sequence[float | None], threshold: float = WITHIN,
                 rule: str = "kept") -> int | None:  # fmt: skip
    """The budget at which a learning curve (``gaps[i]`` at ``steps[i]``, in %, None where
    there is no gap) is within ``threshold`` by ``rule`` (``"kept"`` or ``"first"``, see the
    module docstring); None if it never is."""
    rule = check_choice("rule", rule, RULES)
    if len(steps) != len(gaps):
        raise ValueError(f"steps has {len(steps)} points and gaps {len(gaps)}; expected one each")
    within = [g is not None and math.isfinite(g) and g <= threshold for g in gaps]
    if rule == "first":
        return next((int(s) for s, w in zip(steps, within, strict=True) if w), None)
    answer = None
    for s, w in zip(reversed(steps), reversed(within), strict=True):
        if not w:
            break
        answer = int(s)
    return answer


def across_seeds(per_seed: Sequence[int | None]) -> dict[str, Any]:
    """``{"median", "low", "high", "within", "seeds"}`` of the seeds' steps (None: never
    within): the median with never as infinity (None if it is; the lower median for an even
    count), the fewest and most steps of the seeds within, how many are."""
    reached = sorted(int(s) for s in per_seed if s is not None)
    ordered = reached + [math.inf] * (len(per_seed) - len(reached))
    median = ordered[(len(ordered) - 1) // 2] if ordered else math.inf
    return {
        "median": None if math.isinf(median) else int(median),
        "low": reached[0] if reached else None,
        "high": reached[-1] if reached else None,
        "within": len(reached),
        "seeds": len(per_seed),
    }
