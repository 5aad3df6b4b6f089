"""The suite's model-based references: ``python -m benchmarks.suite`` without ``--policy``.

For every task (:data:`sdjls_gym.SUITE`, or ``--tasks``), on the same episodes (common random
numbers):

* the one-step receding-horizon controller (P3) over its levels ``xi``
  (:func:`benchmarks.core.reference.curve_xis`), with individual chance constraints (the *reference
  curve* every normalized gap is measured against) and with joint ones;
* the 3-step scenario-tree controller (``ScenarioTreeController(..., steps=3)``) over
  :data:`~benchmarks.core.reference.TREE_XIS` (VTOL: its
  :data:`~benchmarks.core.reference.TREE_BY_TASK` levels), on the same episodes (its decisions
  cost 100 to 1000 times the one-step controller's; each level's run is kept in
  ``<out>/tree_levels``, :mod:`benchmarks.core.tree_levels`), its gaps measured against the
  one-step curve;
* linear feedback ``u = K x`` with the task's gains, and the MJLS LQ regulator
  (``MJLSLQRController(model, "average")``, constraints ignored), scored by
  :func:`benchmarks.evaluate.evaluate`.

Each controller's normalized gap (% of the reference curve's cost at its own violation
frequency, :mod:`benchmarks.suite`) and, for the controllers at the task's own level (the joint
RHC, the 3-step tree) and the two baselines, rliable's aggregate across the tasks. Outputs under
``--out`` (default :data:`DEFAULT_OUT`; with ``--quick`` a new temporary folder,
:func:`benchmarks.core.cli.quick_folder`): ``summary.json``, ``summary.csv``, ``REPORT.md`` (written atomically), one
cost-violation figure per task (``fig_<env id>.png``) and ``fig_aggregate.png``
(:mod:`benchmarks.suite.figures`).
"""

from __future__ import annotations

import csv
import io
import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.aggregate import SuiteAggregate, aggregate_gaps, rliable_modules
from benchmarks.core.evaluate import evaluate, resolve_env
from benchmarks.core.files import stable_floats, write_atomic
from benchmarks.core.frontier import (
    as_seeds,
    bounded_gap,
    gap_reason,
    reference_curve,
    tree_curve,
)
from benchmarks.core.reference import (
    QUICK_TREE,
    TREE_BY_TASK,
    TREE_STEPS,
    TREE_XIS,
    curve_xis,
)
from benchmarks.core.stats import CurveGap, EpisodeStatistics
from benchmarks.core.tree_levels import TREE_STORE, LevelStore
from sdjls_gym.systems import TASKS, Task

__all__ = [
    "DEFAULT_OUT",
    "QUICK_XIS",
    "Point",
    "TaskReferences",
    "run_references",
    "task_references",
]

DEFAULT_OUT = Path("results/suite")
#: ``--quick``: the levels of the one-step curves.
QUICK_XIS: tuple[float, ...] = (0.3, 0.7, 0.9, 0.99)
#: The controllers aggregated across tasks: the family and whether at the task's ``xi``.
AGGREGATED = ("RHC joint", "RHC 3-step", "Linear feedback", "MJLS LQ")


@dataclass(frozen=True)
class Point(EpisodeStatistics):
    """One controller on one task: its statistics and its gap to the reference curve."""

    family: str  # "RHC individual", "RHC joint", "RHC 3-step", "Linear feedback", "MJLS LQ"
    xi: float | None
    gap: CurveGap | None = None
    reason: str | None = None  # why there is no gap (None on the reference curve itself)
    bounded_gap: float | None = None  # every run's score (None on the reference curve itself)


@dataclass(frozen=True)
class TaskReferences:
    """A task's model-based references."""

    env_id: str
    n: int
    m: int
    N: int
    r: int
    horizon: int
    xi: float
    episodes: int
    tree_episodes: int
    points: tuple[Point, ...]

    def at(self, family: str) -> Point:
        """The point of ``family`` at the task's level (or its only point)."""
        pts = [p for p in self.points if p.family == family]
        return next((p for p in pts if p.xi == self.xi), pts[0])


def _point(family: str, xi: float | None, episodes: int, stats: dict[str, Any],
           gap: CurveGap | None = None, reason: str | None = None,
           bounded: float | None = None) -> Point:  # fmt: skip
    keys = ("cost_mean", "cost_ci95", "cost_median", "violation", "violation_wilson95",
            "diverged")  # fmt: skip
    return Point(
        family=family,
        xi=xi,
        episodes=episodes,
        **{k: stats[k] for k in keys},
        gap=gap,
        reason=reason,
        bounded_gap=bounded,
    )


def _against(curve: Any, costs: np.ndarray, violations: np.ndarray, violation: float,
             diverged: int) -> tuple[CurveGap | None, str | None, float]:  # fmt: skip
    """The gap at equal risk to ``curve`` (or why there is none) and the bounded gap
    (:func:`benchmarks.core.frontier.bounded_gap`: every run's score)."""
    score = bounded_gap(curve, costs, violations, int(diverged))  # the paired gap computed once
    reason = gap_reason(violation, diverged, score.gap, curve.violations, curve.costs)
    return (score.gap if reason is None else None), reason, score.value


def task_references(
    task: Task,
    episodes: int,
    seed: int | tuple[int, ...],
    xis: tuple[float, ...],
    tree_episodes: int,
    tree_xis: tuple[float, ...],
    bar: Any = None,
    store: LevelStore | None = None,
    workers: int = 1,
) -> TaskReferences:
    """Score every model-based controller on ``task`` (see the module docstring): ``episodes``
    episodes from each noise seed of ``seed``; the tree on ``tree_episodes`` per seed, against
    the one-step curve on the same episodes; its level runs kept in ``store`` and the missing
    ones run on ``workers`` processes (:func:`benchmarks.core.frontier.tree_curve`)."""
    from controllers import LinearFeedbackController, MJLSLQRController

    spec = resolve_env(task.env_id, dict(task.env_kwargs))
    kw = {"horizon": spec.horizon, "action_bound": spec.action_bound,
          "divergence_bound": spec.divergence_bound, "progress": bar}  # fmt: skip
    pooled = episodes * len(as_seeds(seed))
    ind = reference_curve(task, episodes, seed, xis=xis, **kw)
    joint = reference_curve(task, episodes, seed, xis=xis, constraint="joint", adaptive=False,
                            **kw)  # fmt: skip
    points = [_point("RHC individual", xi, pooled, ind.point(ind.xis.index(xi))) for xi in xis]
    for i, xi in enumerate(joint.xis):
        stats = joint.point(i)
        gap = _against(ind, joint.costs[i], joint.violations[i], stats["violation"],
                       stats["diverged"])  # fmt: skip
        points.append(_point("RHC joint", xi, pooled, stats, *gap))
    t_eps = tree_episodes
    ind_tree = ind if t_eps == episodes else reference_curve(task, t_eps, seed, xis=xis, **kw)
    tree = tree_curve(task, t_eps, seed, tree_xis, steps=TREE_STEPS, store=store, workers=workers,
                      **kw)  # fmt: skip
    for i, xi in enumerate(tree.xis):
        stats = tree.point(i)
        gap = _against(ind_tree, tree.costs[i], tree.violations[i], stats["violation"],
                       stats["diverged"])  # fmt: skip
        points.append(_point("RHC 3-step", xi, t_eps * len(as_seeds(seed)), stats, *gap))
    for family, ctrl in (
        ("Linear feedback", LinearFeedbackController(task.model, task.K, horizon=spec.horizon)),
        ("MJLS LQ", MJLSLQRController(task.model, "average", horizon=spec.horizon)),
    ):
        s = evaluate(ctrl, episodes=episodes, seed=seed, env_id=task.env_id,
                     env_kwargs=dict(task.env_kwargs))  # fmt: skip
        if bar is not None:
            bar.update(spec.horizon)
        gap = _against(ind, s.episode_costs, s.episode_violations, s.violation, s.diverged)
        points.append(_point(family, None, pooled, asdict(s), *gap))
    return TaskReferences(task.env_id, task.n, task.m, task.N, task.r, spec.horizon,
                          float(task.rhc["xi"]), pooled, t_eps * len(as_seeds(seed)),
                          tuple(points))  # fmt: skip


def aggregates(refs: list[TaskReferences]) -> dict[str, SuiteAggregate | list[str]]:
    """rliable's aggregate of each of :data:`AGGREGATED` (one run per task), on the gaps at
    equal risk, or the list of the tasks where it has none (the second view)."""
    out: dict[str, SuiteAggregate | list[str]] = {}
    for family in AGGREGATED:
        pts = [(t.env_id, t.at(family)) for t in refs]
        missing = [f"{env_id}: {p.reason}" for env_id, p in pts if p.gap is None]
        gaps = [p.gap for _, p in pts if p.gap is not None]
        if missing:
            out[family] = missing
        else:
            out[family] = aggregate_gaps(np.array([[g.percent()[0] for g in gaps]]))
    return out


def bounded_aggregates(refs: list[TaskReferences]) -> dict[str, SuiteAggregate]:
    """rliable's aggregate of each of :data:`AGGREGATED` on every task's bounded gap (every
    run counts: +100 for a diverged or riskier-than-the-curve controller)."""
    out: dict[str, SuiteAggregate] = {}
    for family in AGGREGATED:
        values = [t.at(family).bounded_gap for t in refs]
        out[family] = aggregate_gaps(np.array([[float(v) for v in values]]))  # type: ignore[arg-type]
    return out


# ----------------------------------------------------------------------------- files
def _gap_text(p: Point) -> str:
    if p.gap is None:
        if p.reason is None:
            return "-"
        return (
            "outside" if "range" in p.reason else "diverged" if "diverged" in p.reason else "none"
        )
    relative, (lo, hi) = p.gap.percent()
    return f"{relative:+.1f} ({lo:+.1f} to {hi:+.1f})"


def _cv(p: Point) -> str:
    return f"{p.cost_mean:.4g} / {p.violation:.3f}"


def results_table(refs: list[TaskReferences]) -> list[str]:
    """The README's table: per task, each controller's mean cost / violation frequency and
    its gap (% of the one-step curve's cost, 95% interval) at the task's level."""
    lines = [
        "| task | xi | RHC (P3): cost / violation | RHC joint: cost / violation, gap % | "
        "RHC 3-step: cost / violation, gap % | linear feedback: cost / violation, gap % | "
        "MJLS LQ: cost / violation, gap % |",
        "|---|---|---|---|---|---|---|",
    ]
    for t in refs:
        cells = [f"`{t.env_id}`", f"{t.xi:g}", _cv(t.at("RHC individual"))]
        cells += [f"{_cv(t.at(f))}, {_gap_text(t.at(f))}" for f in AGGREGATED]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def write_report(out: Path, refs: list[TaskReferences], aggs: dict[str, Any],
                 meta: dict[str, Any], figures: list[str],
                 bounded: dict[str, SuiteAggregate]) -> None:  # fmt: skip
    lines = [
        "# The suite's model-based references",
        "",
        f"Command: `{meta['command']}` (wall time {meta['wall_time_s'] / 60:.1f} min on "
        f"{meta['machine']}). Generated by `benchmarks/suite/report.py`; numbers in "
        "`summary.json` and `summary.csv`.",
        "",
        f"Settings: {meta['episodes']} episodes per controller and task from each noise seed "
        f"{meta['seed']} (common random numbers); the one-step RHC curves over xi in "
        f"{meta['xis']}; the 3-step tree (fully branched) on "
        f"{meta['tree']}; gaps in % of the one-step individual curve's cost at the controller's "
        "own violation frequency, paired over the episodes, with 95% bootstrap intervals "
        "(the tree's against the one-step curve on its own episodes). 'outside': the violation "
        "frequency lies outside the curve's range (no gap).",
        "",
        "## At each task's level xi",
        "",
        *results_table(refs),
        "",
        "## Across tasks (rliable)",
        "",
        "One run per task (deterministic controllers): the stratified-bootstrap interval of the "
        "IQM is the point itself. P(improvement): share of tasks where the controller is cheaper "
        "than the one-step curve at its violation frequency. Every task counts, by the "
        "controller's bounded gap at the task's level (`benchmarks.core.frontier.bounded_gap`: "
        "+100 for a diverged controller or one riskier than the curve, a safer one against the "
        "curve's strictest level):",
        "",
        "| controller | IQM of the bounded gaps, % (95% CI) | P(improvement over the one-step "
        "RHC) | bounded gap per task (the order above), % |",
        "|---|---|---|---|",
    ]
    for family, a in bounded.items():
        lo, hi = a.iqm_gap_ci95
        per_task = ", ".join(f"{t.at(family).bounded_gap:+.1f}" for t in refs)
        lines.append(f"| {family} | {a.iqm_gap:+.2f} ({lo:+.2f} to {hi:+.2f}) | "
                     f"{a.probability_of_improvement:.2f} | {per_task} |")  # fmt: skip
    lines += [
        "",
        "The second view, the gaps at equal risk, where the controller has one on every task:",
        "",
        "| controller | IQM of the gaps, % (95% CI) | P(improvement over the one-step RHC) |",
        "|---|---|---|",
    ]
    for family, a in aggs.items():
        if isinstance(a, SuiteAggregate):
            lo, hi = a.iqm_gap_ci95
            lines.append(f"| {family} | {a.iqm_gap:+.2f} ({lo:+.2f} to {hi:+.2f}) | "
                         f"{a.probability_of_improvement:.2f} |")  # fmt: skip
        else:
            lines.append(f"| {family} | none: no gap on {len(a)} task(s) | - |")
    lines += ["", "## Per task: every point", ""]
    for t in refs:
        lines += [
            f"### {t.env_id} (n={t.n}, m={t.m}, N={t.N}, r={t.r}, horizon {t.horizon}, "
            f"xi {t.xi:g})",
            "",
            f"![cost against violations](fig_{t.env_id}.png)",
            "",
            "| controller | xi | episodes | mean cost (95% CI) | violation (95% Wilson) | "
            "diverged | gap % (95% CI) |",
            "|---|---|---|---|---|---|---|",
        ]
        for p in t.points:
            lines.append(
                f"| {p.family} | {'-' if p.xi is None else f'{p.xi:g}'} | {p.episodes} | "
                f"{p.cost_mean:.4g} ({p.cost_ci95[0]:.4g} to {p.cost_ci95[1]:.4g}) | "
                f"{p.violation:.3f} ({p.violation_wilson95[0]:.3f} to "
                f"{p.violation_wilson95[1]:.3f}) | {p.diverged} | {_gap_text(p)} |"
            )
        lines.append("")
    lines += ["![aggregate](fig_aggregate.png)", ""] if "fig_aggregate.png" in figures else []
    write_atomic(out / "REPORT.md", "\n".join(lines))


def write_csv(out: Path, refs: list[TaskReferences]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["task", "controller", "xi", "episodes", "cost_mean", "cost_ci95_low",
                "cost_ci95_high", "violation", "violation_wilson95_low",
                "violation_wilson95_high", "diverged", "gap_pct", "gap_pct_ci95_low",
                "gap_pct_ci95_high"])  # fmt: skip
    for t in refs:
        for p in t.points:
            g = p.gap
            gap = ["", "", ""] if g is None else [g.percent()[0], *g.percent()[1]]
            row = [t.env_id, p.family, "" if p.xi is None else p.xi, p.episodes, p.cost_mean,
                   *p.cost_ci95, p.violation, *p.violation_wilson95, p.diverged, *gap]  # fmt: skip
            w.writerow(stable_floats(row))
    write_atomic(out / "summary.csv", buf.getvalue())


# ----------------------------------------------------------------------------- main
def run_references(opts: Any, argv: list[str]) -> dict[str, Any]:
    """Compute and write the references for the parsed options of :mod:`benchmarks.suite`."""
    from tqdm import tqdm

    from benchmarks.core.versions import CORE_PACKAGES, package_versions
    from benchmarks.suite.figures import make_figures

    rliable_modules()  # the aggregate's dependency, before the long computation
    start = time.perf_counter()
    seeds = tuple(range(opts.seed, opts.seed + opts.seeds))
    out = Path(opts.out)
    out.mkdir(parents=True, exist_ok=True)
    plan = []
    for env_id in opts.tasks:
        task = TASKS[env_id]
        xi = float(task.rhc["xi"])
        xis = tuple(sorted({*QUICK_XIS, xi})) if opts.quick else curve_xis(task)
        t_eps, t_xis = (
            QUICK_TREE if opts.quick else (opts.episodes, TREE_BY_TASK.get(env_id, TREE_XIS))
        )
        t_eps = opts.tree_episodes or t_eps
        plan.append((task, xis, t_eps, tuple(sorted({*t_xis, xi}))))
    steps = len(seeds) * sum(t.horizon * (3 * len(xis) + len(t_xis) + 2)
                             for t, xis, _, t_xis in plan)  # fmt: skip
    refs = []
    with tqdm(total=steps, desc="suite references", unit="step",
              disable=opts.no_progress) as bar:  # fmt: skip
        for task, xis, t_eps, t_xis in plan:
            bar.set_postfix_str(task.env_id)
            refs.append(task_references(task, opts.episodes, seeds, xis, t_eps, t_xis, bar,
                                        LevelStore(out / TREE_STORE), opts.workers))  # fmt: skip
    aggs = aggregates(refs)
    bounded = bounded_aggregates(refs)
    wall = time.perf_counter() - start
    meta = {
        "command": "python -m benchmarks.suite" + ("" if not argv else " " + " ".join(argv)),
        "wall_time_s": wall,
        "machine": "a 2-core machine shared with other jobs",
        "episodes": opts.episodes,
        "seed": ", ".join(map(str, seeds)),
        "xis": "{"
        + "; ".join(f"{t.env_id}: {', '.join(f'{x:g}' for x in xis)}" for t, xis, _, _ in plan)
        + "}",  # fmt: skip
        "tree": "; ".join(
            f"{t.env_id}: {e} episodes x {len(seeds)} seed(s) at xi "
            f"{', '.join(f'{x:g}' for x in txs)}"
            for t, _, e, txs in plan
        ),  # fmt: skip
    }
    summary = {
        "command": meta["command"],
        "options": {
            "quick": bool(opts.quick),
            "episodes": opts.episodes,
            "seed": opts.seed,
            "seeds": opts.seeds,
            "tasks": list(opts.tasks),
            "tree_episodes": opts.tree_episodes,
        },  # fmt: skip
        "wall_time_s": wall,
        "versions": package_versions(CORE_PACKAGES + ("rliable",)),
        "tree": {"steps": TREE_STEPS, "plan": meta["tree"]},
        "tasks": [json.loads(json.dumps(asdict(t))) for t in refs],
        "aggregates": {
            f: a.to_dict() if isinstance(a, SuiteAggregate) else {"missing": a}
            for f, a in aggs.items()
        },
        "bounded_aggregates": {f: a.to_dict() for f, a in bounded.items()},
        "figures": [f"fig_{t.env_id}.png" for t in refs] + ["fig_aggregate.png"],
    }
    # the numbers first: a failing figure must not lose a long computation
    write_atomic(out / "summary.json", json.dumps(stable_floats(summary), indent=1) + "\n")
    write_csv(out, refs)
    figures = make_figures(out, refs, aggs)
    write_report(out, refs, aggs, meta, figures, bounded)
    print(f"wrote {out}/REPORT.md ({wall / 60:.1f} min)", file=sys.stderr)
    return summary
