"""The learning curve of identify + RHC: one point per (task, seed, budget), each cached on disk.

A point is :func:`~benchmarks.identify.learner.learn` at one budget of the grid
(:func:`~benchmarks.identify.steps.step_grid`), scored by the core's protocol
(:func:`benchmarks.core.evaluate.evaluate` on the task's raw environment, the paired gap to the
task's one-step RHC curve, the true-model controller's): every budget of a seed re-identifies on
the first episodes of one exploration of that seed (certainty equivalence, re-identified on all
the data at each budget). Beside the learning curve, each task's *true-model design* point: the
same design (:func:`~benchmarks.identify.learner.design`) on the true model, the learner's limit.

Each point is a small JSON file ``points/<env id>/<seed>-<steps>-<fingerprint>.json`` in the
output folder, written as soon as it is scored; the fingerprint hashes everything the point
depends on (the task's data, the exploration and its length, the learner's rules, the
evaluation's episodes and seeds), so a run that is started again skips the points it has and
never mixes in a point of another configuration.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks.core.evaluate import Score, evaluate
from benchmarks.core.files import jsonable, stable_floats, write_atomic
from benchmarks.identify.learner import (
    EXPLORATION,
    EXPLORATION_SEED_OFFSET,
    FALLBACKS,
    Exploration,
    design,
    explore,
    learn,
)
from controllers import InsufficientDataError
from sdjls_gym.systems import Task

__all__ = [
    "EVAL_EPISODES",
    "EVAL_SEEDS",
    "Plan",
    "eval_seed",
    "fingerprint",
    "run_task",
    "score_record",
]

#: The evaluation's noise seeds. One seed while the core's ``evaluate`` takes one; when it pools
#: several (``evaluate(..., seed=(0, 1, 2))``), set ``(0, 1, 2)`` here: :func:`eval_seed` then
#: passes the tuple, and the points' fingerprints change, so the next run scores them again.
EVAL_SEEDS: tuple[int, ...] = (0,)
#: Evaluation episodes per point (per seed).
EVAL_EPISODES = 1000


def eval_seed() -> Any:
    """The ``seed`` argument of :func:`~benchmarks.core.evaluate.evaluate`: the one seed of
    :data:`EVAL_SEEDS`, or the tuple when it holds several."""
    return EVAL_SEEDS[0] if len(EVAL_SEEDS) == 1 else EVAL_SEEDS


@dataclass(frozen=True)
class Plan:
    """What one task's learning curve computes.

    Attributes
    ----------
    task : Task
    seeds : tuple of int
        The exploration seeds.
    grid : tuple of int
        The budgets, env steps (whole episodes of the horizon), increasing.
    episodes : int
        Evaluation episodes per point.
    """

    task: Task
    seeds: tuple[int, ...]
    grid: tuple[int, ...]
    episodes: int

    @property
    def explored(self) -> int:
        """Episodes each seed explores: the largest budget's (smaller budgets are prefixes)."""
        return self.grid[-1] // self.task.horizon


def fingerprint(plan: Plan, seed: int | None, steps: int | None) -> str:
    """16 hex digits hashing everything one point depends on (``seed = steps = None``: the
    task's true-model design point)."""
    t = plan.task
    config = {
        "task": {"env_id": t.env_id, "model": t.model.to_dict(), "K": t.K, "rhc": dict(t.rhc),
                 "horizon": t.horizon, "action_bound": t.action_bound},
        "learner": {"exploration": EXPLORATION[t.env_id], "offset": EXPLORATION_SEED_OFFSET,
                    "policy_stream": 12345, "explored": plan.explored, "prior": "uniform",
                    "prior_count": 1.0, "fallbacks": FALLBACKS},
        "evaluation": {"episodes": plan.episodes, "seeds": EVAL_SEEDS},
        "point": {"seed": seed, "steps": steps},
    }  # fmt: skip
    text = json.dumps(jsonable(config), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def point_path(out: Path, plan: Plan, seed: int | None, steps: int | None) -> Path:
    name = "true_model" if seed is None else f"s{seed}-{steps}"
    return out / "points" / plan.task.env_id / f"{name}-{fingerprint(plan, seed, steps)}.json"


def score_record(score: Score) -> dict[str, Any]:
    """The fields of a :class:`~benchmarks.core.evaluate.Score` a point keeps."""
    g = score.curve_gap
    return {
        "cost_mean": score.cost_mean,
        "cost_ci95": list(score.cost_ci95),
        "violation": score.violation,
        "violation_wilson95": list(score.violation_wilson95),
        "diverged": score.diverged,
        "gap": None if g is None else g.relative,
        "gap_ci95": None if g is None or g.relative_ci95 is None else list(g.relative_ci95),
        "gap_mean": None if g is None else g.mean,
        "curve_cost": None if g is None else g.curve_cost,
        "curve_xi": None if g is None else g.xi,
        "gap_reason": score.curve_gap_reason,
    }


def _score(controller: Any, plan: Plan) -> tuple[str, str | None, dict[str, Any] | None]:
    """``(status, message, score)`` of a controller on the task's raw environment."""
    try:
        score = evaluate(controller, episodes=plan.episodes, seed=eval_seed(),
                         env_id=plan.task.env_id)  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - a controller on a poor estimate may fail: a point
        return "evaluation_failed", f"{type(exc).__name__}: {exc}", None
    return "ok", None, score_record(score)


def compute_point(plan: Plan, seed: int | None, steps: int | None,
                  exploration: Exploration | None) -> dict[str, Any]:  # fmt: skip
    """One point's record (not yet written)."""
    cpu0 = time.process_time()
    t = plan.task
    record: dict[str, Any] = {"env_id": t.env_id, "seed": seed, "steps": steps,
                              "fingerprint": fingerprint(plan, seed, steps)}  # fmt: skip
    info = None
    if seed is None:  # the true-model design: the learner's limit
        controller, fallback = design(t, t.model)
        d = controller.design
        assert d is not None
        info = {"fallback": fallback, "K_source": d.K_source, "Psi_source": d.Psi_source}
        status, message, score = _score(controller, plan)
    else:
        assert steps is not None
        try:
            controller, learned = learn(t, steps, seed, exploration=exploration)
        except InsufficientDataError as exc:
            status, message, score = "insufficient_data", str(exc), None
        else:
            info = jsonable(dataclasses.asdict(learned))
            status, message, score = _score(controller, plan)
    record.update(status=status, message=message, info=info, score=score,
                  cpu_s=time.process_time() - cpu0)  # fmt: skip
    return record


def _write(path: Path, record: dict[str, Any]) -> dict[str, Any]:
    """Write ``record`` and return it as written (floats at stable precision)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    written: dict[str, Any] = stable_floats(jsonable(record))
    write_atomic(path, json.dumps(written, indent=1) + "\n")
    return written


def _read(path: Path) -> dict[str, Any] | None:
    try:
        return dict(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError):
        return None  # missing or torn: computed again


def run_task(plan: Plan, out: Path, log: Callable[[str], None]) -> dict[str, Any]:
    """Every point of ``plan`` (cached ones read, the others computed and written), and the
    CPU seconds of this call's explorations: ``{"points": [...], "true_model": {...},
    "exploration_cpu_s": float}``."""
    t = plan.task
    points: list[dict[str, Any]] = []
    explore_cpu = 0.0
    for seed in plan.seeds:
        exploration = None
        for steps in plan.grid:
            path = point_path(out, plan, seed, steps)
            record = _read(path)
            if record is None:
                if exploration is None:
                    cpu0 = time.process_time()
                    exploration = explore(t, plan.explored, seed)
                    explore_cpu += time.process_time() - cpu0
                record = _write(path, compute_point(plan, seed, steps, exploration))
                log(_line(record))
            points.append(record)
    path = point_path(out, plan, None, None)
    oracle = _read(path)
    if oracle is None:
        oracle = _write(path, compute_point(plan, None, None, None))
        log(_line(oracle))
    return {"points": points, "true_model": oracle, "exploration_cpu_s": explore_cpu}


def _line(record: dict[str, Any]) -> str:
    who = "true-model design" if record["seed"] is None else (
        f"seed {record['seed']}, {record['steps']} steps")  # fmt: skip
    score = record["score"]
    if score is None:
        what = f"{record['status']}: {str(record['message'])[:100]}"
    elif score["gap"] is None:
        what = f"no gap ({score['gap_reason']})"
    else:
        what = f"gap {score['gap']:+.1f}% at violation {score['violation']:.3f}"
    return f"{record['env_id']}, {who}: {what} ({record['cpu_s']:.1f} s CPU)"
