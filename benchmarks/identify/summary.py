"""A task's learning curves in numbers: identify + RHC's and the agents', the steps each needs.

:func:`task_summary` turns the points of :func:`benchmarks.identify.run.run_task` and the
agents' curves (:mod:`benchmarks.identify.agents`) into one JSON-ready dict: the learner's curve
(per budget, the median and interquartile range of the gap over the seeds), the steps to come
within 5% by each rule of :func:`~benchmarks.identify.steps.steps_within` for the learner and for
each agent configuration (per seed and across seeds), the gaps at each agent's full budget, and
the true-model design point.

Across seeds, a point without a gap counts as worse than any gap (``+inf``): the median and the
quartiles are order statistics (the lower median, the 25% quantile by the lower and the 75% by
the higher rank: the 2nd, 3rd and 4th of 5 seeds), so that they are numbers exactly when enough
seeds have a gap.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from benchmarks.identify.agents import AgentCurve, configs
from benchmarks.identify.steps import RULES, WITHIN, across_seeds, steps_within

__all__ = ["POINT_FIELDS", "order_stats", "point_row", "task_summary"]

#: The fields of one point in ``summary.json`` and ``summary.csv``.
POINT_FIELDS = ("env_id", "seed", "steps", "episodes", "status", "fallback", "error_A",
                "error_B", "error_AB", "error_cov", "error_P", "cost_mean", "violation",
                "diverged", "gap", "gap_ci95_low", "gap_ci95_high", "gap_reason", "cpu_s")  # fmt: skip


def point_row(p: dict[str, Any]) -> dict[str, Any]:
    """One point's record (:func:`benchmarks.identify.run.compute_point`) as a flat row of
    :data:`POINT_FIELDS` (the true-model design with ``seed`` and ``steps`` None)."""
    info, score = p["info"] or {}, p["score"] or {}
    errors = info.get("errors", {})
    ci = score.get("gap_ci95") or (None, None)
    return {
        "env_id": p["env_id"], "seed": p["seed"], "steps": p["steps"],
        "episodes": info.get("episodes"), "status": p["status"], "fallback": info.get("fallback"),
        **{f"error_{k}": errors.get(k) for k in ("A", "B", "AB", "cov", "P")},
        **{k: score.get(k) for k in ("cost_mean", "violation", "diverged", "gap")},
        "gap_ci95_low": ci[0], "gap_ci95_high": ci[1], "gap_reason": score.get("gap_reason"),
        "cpu_s": round(float(p["cpu_s"]), 3),
    }  # fmt: skip


def order_stats(values: Sequence[float | None]) -> dict[str, float | None]:
    """``{"median", "q25", "q75"}`` of ``values`` with None as ``+inf`` (see the module
    docstring); each None where it is infinite or there are no values."""
    if not values:
        return {"median": None, "q25": None, "q75": None}
    arr = np.array([math.inf if v is None else float(v) for v in values])
    out = {
        "median": float(np.quantile(arr, 0.5, method="lower")),
        "q25": float(np.quantile(arr, 0.25, method="lower")),
        "q75": float(np.quantile(arr, 0.75, method="higher")),
    }
    return {k: (None if math.isinf(v) else v) for k, v in out.items()}


def _gap(record: dict[str, Any]) -> float | None:
    score = record.get("score")
    return None if score is None else score.get("gap")


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def _learner_curve(grid: Sequence[int], seeds: Sequence[int],
                   points: list[dict[str, Any]]) -> list[dict[str, Any]]:  # fmt: skip
    at = {(p["seed"], p["steps"]): p for p in points}
    curve = []
    for steps in grid:
        row = [at[(s, steps)] for s in seeds if (s, steps) in at]
        gaps = [_gap(p) for p in row]
        scored = [p["score"] for p in row if p["score"] is not None]
        learned = [p["info"] for p in row if p["info"] is not None]
        curve.append({
            "steps": int(steps),
            **order_stats(gaps),
            "seeds": len(row),
            "with_gap": sum(g is not None for g in gaps),
            "violation_median": _median([s["violation"] for s in scored]),
            "no_estimate": sum(p["status"] == "insufficient_data" for p in row),
            "failed": sum(p["status"] == "evaluation_failed" for p in row),
            "diverged": sum(bool(s["diverged"]) for s in scored),
            "fallbacks": sum(i["fallback"] != "none" for i in learned),
            "error_AB_median": _median([i["errors"]["AB"] for i in learned]),
            "error_P_median": _median([i["errors"]["P"] for i in learned]),
            "error_cov_median": _median([i["errors"]["cov"] for i in learned]),
        })  # fmt: skip
    return curve


def _within(curves: Mapping[int, tuple[Sequence[int], Sequence[float | None]]]) -> dict[str, Any]:
    """Per rule: each seed's steps to come within and their summary across seeds."""
    out: dict[str, Any] = {}
    for rule in RULES:
        per_seed = {s: steps_within(st, g, WITHIN, rule) for s, (st, g) in curves.items()}
        out[rule] = {"per_seed": {str(s): v for s, v in per_seed.items()},
                     **across_seeds(list(per_seed.values()))}  # fmt: skip
    return out


def _agents(agent_curves: list[AgentCurve], budgets: dict[str, int],
            learner_at: dict[int, dict[str, Any]], T: int) -> dict[str, Any]:  # fmt: skip
    out: dict[str, Any] = {}
    for config, runs in configs(agent_curves).items():
        n = min(len(r.steps) for r in runs)
        steps = list(runs[0].steps[:n])
        curve = [{"steps": st, **order_stats([r.gaps[i] for r in runs]),
                  "with_gap": sum(r.gaps[i] is not None for r in runs)}
                 for i, st in enumerate(steps)]  # fmt: skip
        budget = budgets.get(config, steps[-1])
        at = learner_at.get(budget // T * T)
        out[config] = {
            "budget": int(budget),
            "seeds": [r.seed for r in runs],
            "curve": curve,
            "within": _within({r.seed: (r.steps, r.gaps) for r in runs}),
            "final": {**order_stats([r.final_gap for r in runs]),
                      "with_gap": sum(r.final_gap is not None for r in runs)},
            "learner_at_budget": None if at is None else {
                k: at[k] for k in ("steps", "median", "q25", "q75", "with_gap")},
        }  # fmt: skip
    return out


def task_summary(env_id: str, horizon: int, grid: Sequence[int], seeds: Sequence[int],
                 result: dict[str, Any], agent_curves: list[AgentCurve],
                 budgets: dict[str, int]) -> dict[str, Any]:  # fmt: skip
    """One task's summary (see the module docstring) from :func:`~benchmarks.identify.run.
    run_task`'s ``result``, the agents' curves on the task and their budgets."""
    points = result["points"]
    curve = _learner_curve(grid, seeds, points)
    per_seed = {
        s: ([p["steps"] for p in points if p["seed"] == s],
            [_gap(p) for p in points if p["seed"] == s])
        for s in seeds
    }  # fmt: skip
    oracle = result["true_model"]
    return {
        "env_id": env_id,
        "horizon": horizon,
        "grid": [int(g) for g in grid],
        "seeds": list(seeds),
        "learner": {"curve": curve, "within": _within(per_seed)},
        "true_model_design": {
            "gap": _gap(oracle),
            "score": oracle["score"],
            "info": oracle["info"],
            "status": oracle["status"],
        },
        "agents": _agents(agent_curves, budgets, {c["steps"]: c for c in curve}, horizon),
        "points": [point_row(p) for p in [*points, oracle]],
        "cpu_s": float(sum(p["cpu_s"] for p in points) + oracle["cpu_s"]),
    }
