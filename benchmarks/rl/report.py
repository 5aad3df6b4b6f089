"""The RL comparison's records, aggregates and outputs: summary.json, summary.csv, and the
learning-curve table of the reports (the macro task's REPORT.md: :mod:`.macro_report`).

The report is tables and a short fixed text; the reading of the numbers is written by hand in
the README.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.evaluate import Score
from benchmarks.core.files import jsonable, write_atomic
from benchmarks.core.score_table import fmt_steps, row_fields
from benchmarks.core.stats import (
    CurveStatus,
    IntervalCheck,
    mean_ci,
    paired_curve_gap,
    paired_difference,
    wilson,
)
from benchmarks.rl import hyperparams as HP
from benchmarks.rl.records import RunRecord

#: Margin over the target 1 - xi within which a trained agent counts as comparable with the RHC.
COMPARABLE_MARGIN = 0.05


# ----------------------------------------------------------------------------- records
@dataclass
class ControllerResult:
    """A model-based controller, scored; ``xi`` and ``constraint`` for the points of a curve."""

    name: str
    family: str
    score: Score
    xi: float | None = None
    constraint: str | None = None
    tightened_band_empty: float | None = None  # share of (mode, k) with an empty tightened band
    kind: str = "model-based"


def curve_xi(point: ControllerResult) -> float:
    """``point.xi`` of a point of a curve over ``xi``; a ValueError for a result without one."""
    if point.xi is None:
        raise ValueError(f"{point.name!r} has xi = None; expected a point of a curve over xi")
    return point.xi


@dataclass
class RunResult:
    """A trained seed, scored."""

    run: RunRecord
    score: Score
    kind: str = "rl-seed"

    @property
    def name(self) -> str:
        return self.run.name


@dataclass
class Aggregate:
    """The seeds of one (algorithm, variant), pooled (see :func:`aggregate`)."""

    name: str
    algo: str
    variant: str
    seeds: int
    episodes: int
    steps: int
    cost_mean: float
    cost_ci95: tuple[float, float]
    cost_median: float
    violation: float
    violation_wilson95: tuple[float, float]
    violation_seed_range: tuple[float, float]
    diverged: int
    timesteps: int
    train_time_s: float
    decision_time_batched_s: float
    decision_time_single_s: float
    final_beta: float | None
    kind: str = "rl-aggregate"


@dataclass(frozen=True)
class AgainstAgent:
    """A model-based controller's cost minus the best agent's, paired over the episodes."""

    name: str
    agent: str
    mean: float
    ci95: tuple[float, float]  # 95% bootstrap interval


@dataclass(frozen=True)
class AgainstCurve:
    """A controller's cost minus a model-based curve at its own violation frequency."""

    name: str
    curve: str  # the curve's family
    violation: float  # the controller's violation frequency
    cost_mean: float
    curve_cost: float  # the curve's cost at that frequency
    mean: float  # cost_mean - curve_cost, paired over the episodes
    ci95: tuple[float, float]  # 95% bootstrap interval
    xi: float | None  # the curve's xi at that frequency


@dataclass
class Summary:
    """Everything the RL comparison computed (written as summary.json)."""

    command: str
    options: dict[str, Any]
    versions: dict[str, str | None]
    timesteps: dict[str, dict[str, int]]
    hyperparams: dict[str, Any]
    model_based: list[ControllerResult]
    rl_runs: list[RunResult]
    rl_aggregates: list[Aggregate]
    learning_curves: list[CurveStatus]
    violation_interval_check: dict[str, IntervalCheck | None] | None
    best_config: str | None
    best_config_comparable: bool
    best_agent: str | None
    against_best_agent: list[AgainstAgent]
    against_curves: dict[str, list[AgainstCurve]]
    figures: list[str]

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["model_based"] = [result_json(r) for r in self.model_based]
        out["rl_runs"] = [result_json(r) for r in self.rl_runs]
        return json.loads(json.dumps(out))


def result_json(r: ControllerResult | RunResult) -> dict[str, Any]:
    """A scored controller or run as summary.json holds it (a run without its configuration)."""
    if isinstance(r, RunResult):
        data = {k: v for k, v in r.run.to_json().items() if k != "config"}
        tail = {k: data.pop(k) for k in ("learning_curve", "dual_ascent")}
        return {**data, "score": r.score.to_dict(), **tail}
    data = {k: v for k, v in asdict(r).items() if k != "score"}
    return {**data, "score": r.score.to_dict()}


# ----------------------------------------------------------------------------- aggregation
def aggregate(runs: list[RunResult]) -> list[Aggregate]:
    """One row per (algorithm, variant): seeds pooled.

    The cost is the mean over seeds of each seed's mean, with a Student-t 95% interval over seeds
    (the spread between trainings, which dominates; cut at 0; for a single seed that seed's
    interval over episodes), and the median of the seeds' medians. The violation frequency is
    pooled over every seed's steps, with its Wilson interval; ``violation_seed_range`` shows the
    spread between seeds.
    """
    groups: dict[tuple[str, str], list[RunResult]] = {}
    for r in runs:
        groups.setdefault((r.run.algo, r.run.variant), []).append(r)
    rows = []
    for (algo, variant), rs in groups.items():
        scores = [r.score for r in rs]
        means = np.array([s.cost_mean for s in scores])
        if len(rs) == 1:  # no spread between trainings to show: the episodes' interval
            mean, (lo, hi) = float(means[0]), scores[0].cost_ci95
        else:
            mean, lo, hi = mean_ci(means, floor=0.0)
        steps = sum(s.episodes * s.steps for s in scores)
        count = int(round(sum(s.violation * s.episodes * s.steps for s in scores)))
        vlo, vhi = wilson(count, steps)
        freqs = [s.violation for s in scores]
        betas = [r.run.final_beta for r in rs]
        known = [b for b in betas if b is not None]
        if known and len(known) < len(betas):
            raise ValueError(
                f"{algo} {variant}: final_beta = {betas}; expected a value on every seed or on none"
            )
        rows.append(
            Aggregate(
                name=f"{algo.upper()} {variant}",
                algo=algo,
                variant=variant,
                seeds=len(rs),
                episodes=int(sum(s.episodes for s in scores)),
                steps=scores[0].steps,
                cost_mean=float(mean),
                cost_ci95=(float(lo), float(hi)),
                cost_median=float(np.median([s.cost_median for s in scores])),
                violation=count / steps,
                violation_wilson95=(float(vlo), float(vhi)),
                violation_seed_range=(min(freqs), max(freqs)),
                diverged=int(sum(s.diverged for s in scores)),
                timesteps=int(np.mean([r.run.timesteps for r in rs])),
                train_time_s=float(np.mean([r.run.train_time_s for r in rs])),
                decision_time_batched_s=float(np.mean([s.decision_time_batched_s for s in scores])),
                decision_time_single_s=float(np.mean([s.decision_time_single_s for s in scores])),
                final_beta=float(np.mean(known)) if known else None,
            )
        )
    return rows


def comparable(row: Aggregate, target: float) -> bool:
    """Comparable with the RHC at risk level ``target``: no diverged episode and a violation
    frequency of at most ``target`` + :data:`COMPARABLE_MARGIN`."""
    return row.diverged == 0 and row.violation <= target + COMPARABLE_MARGIN


def best_config(aggs: list[Aggregate], target: float) -> Aggregate | None:
    """The configuration with the lowest mean cost among the :func:`comparable` ones; if there is
    none, the one with the fewest diverged episodes, then the fewest violations."""
    if not aggs:
        return None
    ok = [a for a in aggs if comparable(a, target)]
    if ok:
        return min(ok, key=lambda a: a.cost_mean)
    return min(aggs, key=lambda a: (a.diverged, a.violation))


def best_agent(aggs: list[Aggregate], runs: list[RunResult], target: float) -> RunResult | None:
    """Of :func:`best_config`'s seeds, the one with the median mean cost (the lower middle one
    for an even count; not the cheapest, which would pick the luckiest training on the very
    episodes it is scored on)."""
    best = best_config(aggs, target)
    if best is None:
        return None
    seeds = sorted(
        (r for r in runs if (r.run.algo, r.run.variant) == (best.algo, best.variant)),
        key=lambda r: r.score.cost_mean,
    )
    return seeds[(len(seeds) - 1) // 2]


def against_best_agent(
    model_based: list[ControllerResult], best: RunResult | None
) -> list[AgainstAgent]:
    """Each model-based controller's cost minus the best agent's, paired over the episodes,
    with its 95% bootstrap interval (:func:`benchmarks.core.stats.paired_difference`)."""
    if best is None:
        return []
    out = []
    for r in model_based:
        mean, ci = paired_difference(r.score.episode_costs, best.score.episode_costs)
        out.append(AgainstAgent(r.name, best.name, mean, (float(ci[0]), float(ci[1]))))
    return out


def against_curve(
    points: list[ControllerResult], others: list[ControllerResult | RunResult]
) -> list[AgainstCurve]:
    """Each of ``others``' cost minus the curve through ``points`` (a model-based curve over
    ``xi``, scored on the same episodes) at its own violation frequency, paired over the
    episodes with a 95% bootstrap interval (:func:`benchmarks.core.stats.paired_curve_gap`).

    Rows with a diverged episode, or whose frequency lies outside the curve's range, are left
    out; so is everything when the curve has fewer than 2 points.
    """
    points = sorted(points, key=curve_xi)
    if len(points) < 2:
        return []
    c_costs = np.stack([p.score.episode_costs for p in points])
    c_viols = np.stack([p.score.episode_violations for p in points])
    xis = [curve_xi(p) for p in points]
    out = []
    for r in others:
        if r.score.diverged:
            continue
        g = paired_curve_gap(r.score.episode_costs, r.score.episode_violations, c_costs, c_viols,
                             xis)  # fmt: skip
        if g is None:
            continue
        out.append(AgainstCurve(r.name, points[0].family, g.violation, r.score.cost_mean,
                                g.curve_cost, g.mean, g.ci95, g.xi))  # fmt: skip
    return out


# ----------------------------------------------------------------------------- csv
CSV_HEADER = [
    "name", "kind", "algo", "variant", "seed", "xi", "episodes", "episode_cost_mean",
    "episode_cost_lo", "episode_cost_hi", "episode_cost_median", "violation", "violation_lo",
    "violation_hi", "diverged", "timesteps", "train_time_s", "decision_time_batched_s",
    "decision_time_single_s", "final_beta", "curve_gap", "curve_gap_lo", "curve_gap_hi",
    "violation_episode_lo", "violation_episode_hi",
]  # fmt: skip


def csv_row(r: Any) -> list[Any]:
    name, eps, mean, (lo, hi), median, v, (vlo, vhi), div, steps, train, dtb, dts = row_fields(r)
    run = r.run if isinstance(r, RunResult) else r
    score = getattr(r, "score", None)
    gap = None if score is None else score.curve_gap
    beta = getattr(run, "final_beta", None)
    return [
        name, r.kind, getattr(run, "algo", ""), getattr(run, "variant", ""),
        getattr(run, "seed", ""), "" if getattr(r, "xi", None) is None else r.xi, eps,
        f"{mean:.6g}", f"{lo:.6g}", f"{hi:.6g}", f"{median:.6g}", f"{v:.6f}", f"{vlo:.6f}",
        f"{vhi:.6f}", div, steps, f"{train:.1f}", f"{dtb:.3g}", f"{dts:.3g}",
        "" if beta is None else f"{beta:.6g}",
        *(["", "", ""] if gap is None else [f"{g:.6g}" for g in (gap.mean, *gap.ci95)]),
        *(["", ""] if score is None else [f"{e:.6f}" for e in score.violation_episode_t95]),
    ]  # fmt: skip


def write_csv(path: Path, rows: list[Any]) -> None:
    """``summary.csv``, written atomically (:func:`benchmarks.core.files.write_atomic`)."""
    buffer = io.StringIO(newline="")
    w = csv.writer(buffer)
    w.writerow(CSV_HEADER)
    for r in rows:
        w.writerow(csv_row(r))
    write_atomic(path, buffer.getvalue())


def curve_table(status: list[CurveStatus]) -> list[str]:
    """The learning-curve table of REPORT.md: the flatness test per configuration."""
    lines = [
        "| agent | training steps | late window (steps) | violation frequency, late | "
        "change | diverged share, late | change | median cost change | flat |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in status:
        dc = s.cost_rel_change
        if dc is None:
            cost = "- (median episode diverges)"
        else:
            cost = f"{100 * dc:.1f}%" if dc < 10 else "> 1000%"
        lo, hi = s.late_window
        lines.append(
            f"| {s.algo.upper()} {s.variant} | {fmt_steps(s.timesteps)} | {fmt_steps(lo)}-"
            f"{fmt_steps(hi)} | {s.violation_late:.3f} | {s.violation_change:.4f} | "
            f"{s.diverged_share_late:.2f} | {s.diverged_share_change:.4f} | {cost} | "
            f"{'yes' if s.flat else '**no**'} |"
        )
    return lines


def hyperparams_record(algos: list[str], variants: list[str]) -> dict[str, Any]:
    """The hyperparameters a summary records."""
    return jsonable(
        {
            "algorithms": {a: HP.HYPERPARAMS[a] for a in algos},
            "variant_changes": {
                f"{a} {v}": changes
                for (a, v), changes in HP.HYPERPARAMS_VARIANT.items()
                if a in algos and v in variants
            },
            "env": HP.ENV,
            "betas": HP.BETAS,
            "lagrangian": HP.LAGRANGIAN,
            "residual_nu_bound": HP.RESIDUAL_NU_BOUND,
            "learning_curve": HP.LEARNING_CURVE,
        }
    )
