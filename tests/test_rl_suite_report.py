"""The suite comparison's report across tasks (issue 31, "Reported as RL researchers report"):
which runs and tasks enter rliable's tables, the IQM against a hand computation, the gap of a
learning-curve point, and the sample-efficiency curve. Synthetic, seeded tables; the end-to-end
``--quick`` run on two tasks is in tests/test_rl_suite.py."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.core.aggregate import aggregate_gaps, iqm_interval
from benchmarks.core.frontier import WORST_GAP, ReferenceCurve
from benchmarks.core.stats import CurveGap, paired_curve_gap
from benchmarks.rl.suite_report import across_tasks, gap_table, point_gap, sample_efficiency

RESAMPLES = 100  # rliable's bootstrap is slow (a Mann-Whitney test per task and resample)


def _iqm(values: np.ndarray) -> float:
    """The interquartile mean by hand: 25% of the values cut from each end (rliable's rule,
    scipy's trim_mean: int(0.25 n) from each end)."""
    flat = np.sort(np.asarray(values, dtype=np.float64).ravel())
    cut = int(0.25 * flat.size)
    return float(flat[cut : flat.size - cut].mean())


def test_iqm_interval_matches_a_hand_computation_and_aggregate_gaps():
    """4 seeds x 5 tasks (20 values: 5 cut from each end): the IQM by hand, and the same
    stratified-bootstrap interval as aggregate_gaps draws from the same seed."""
    gaps = np.random.default_rng(5).normal(-3.0, 15.0, size=(4, 5))
    point, ci = iqm_interval(gaps, RESAMPLES)
    assert point == pytest.approx(_iqm(gaps), rel=1e-12)
    assert ci == aggregate_gaps(gaps, RESAMPLES).iqm_gap_ci95
    assert ci[0] < point < ci[1]
    assert iqm_interval(gaps, RESAMPLES, seed=1)[1] != ci  # the interval is a bootstrap
    for bad in (np.zeros((0, 2)), np.array([[1.0, np.inf]])):
        with pytest.raises(ValueError, match="gaps = "):
            iqm_interval(bad)


def test_gap_table_leaves_out_tasks_without_a_gap_and_seeds_not_on_every_task():
    """A task where one kept run has no gap is left out whole (not only that run: dropping it
    would keep the lucky seeds); a task without runs is named; of the other tasks the seeds
    kept on all of them are used, and the others are named."""
    ok = {s: (float(s) + 1.0, None) for s in range(3)}
    cells = {
        "A": dict(ok),
        "B": {0: (5.0, None), 1: (None, "2 episode(s) diverged"), 2: (7.0, None)},
        "C": {0: (-1.0, None), 1: (-2.0, None)},  # seed 2 not kept (yet)
        "D": {},
    }
    table, tasks, seeds, left = gap_table(cells)
    assert tasks == ("A", "C") and seeds == (0, 1)
    np.testing.assert_array_equal(table, [[1.0, -1.0], [2.0, -2.0]])
    assert left == ("no kept run on D", "B: seed 1: 2 episode(s) diverged",
                    "seed(s) 2: not kept on every task used")  # fmt: skip
    assert gap_table({"D": {}, "B": cells["B"]})[0] is None


def _agent(task: str, config: str, seed: int, gap: float | None, tree: float | None,
           curve: list[float]) -> SimpleNamespace:  # fmt: skip
    """What across_tasks and sample_efficiency read of an AgentScore: a missing gap at equal
    risk counts as the worst value in the bounded gaps."""

    def relative(g: float | None) -> CurveGap | None:
        return None if g is None else CurveGap(g, (g, g), 1.0, 0.1, None, g, (g, g))

    points = [SimpleNamespace(timesteps=1000 * j) for j in range(len(curve))]
    return SimpleNamespace(
        config=config, run=SimpleNamespace(seed=seed, task=task, learning_curve=points),
        gap=relative(gap), reason=None if gap is not None else "3 episode(s) diverged",
        bounded=WORST_GAP if gap is None else gap,
        tree_gap=relative(tree), tree_reason=None if tree is not None else "violation frequency "
        "0.5 is above the curve's range",
        tree=SimpleNamespace(value=WORST_GAP if tree is None else tree),
        curve_gaps=tuple(curve),
    )  # fmt: skip


def test_across_tasks_and_sample_efficiency_against_a_hand_computation():
    """3 seeds x 4 tasks of one configuration, seeded: rliable's IQM and probability of
    improvement are the hand ones on every run's bounded gap (the run riskier than the tree's
    curve counts at the worst value); the equal-risk view leaves out the task where a run has no
    gap; along training the IQM is the hand one at every point."""
    rng = np.random.default_rng(17)
    gaps = rng.normal(0.0, 10.0, size=(3, 4))
    tree = gaps + 5.0
    curves = rng.normal(20.0, 10.0, size=(3, 4, 3))
    curves[1, 2, 0] = WORST_GAP  # the untrained policy of one run diverges: the worst value
    tasks = ["T0", "T1", "T2", "T3"]
    reports = []
    for t, task in enumerate(tasks):
        agents = [
            _agent(task, "ppo_residual", s, gaps[s, t], None if (s, t) == (2, 3) else tree[s, t],
                   [float(v) for v in curves[s, t]])
            for s in range(3)
        ]  # fmt: skip
        reports.append(SimpleNamespace(env_id=task, agents=agents))
    (c,) = across_tasks(reports, ["ppo_residual"], RESAMPLES)
    assert c.bounded_tasks == tuple(tasks) and c.bounded_seeds == (0, 1, 2)
    assert c.bounded_rhc.iqm_gap == pytest.approx(_iqm(gaps), rel=1e-12)
    poi = np.mean(np.mean(gaps < 0, axis=0))  # no ties with 0 in continuous draws
    assert c.bounded_rhc.probability_of_improvement == pytest.approx(poi)
    counted = tree.copy()
    counted[2, 3] = WORST_GAP
    assert c.bounded_tree.iqm_gap == pytest.approx(_iqm(counted), rel=1e-12)
    assert c.vs_rhc.iqm_gap == pytest.approx(_iqm(gaps), rel=1e-12)
    assert c.tree_tasks == ("T0", "T1", "T2")
    assert c.tree_left_out == ("T3: seed 2: riskier than the curve",)
    assert c.vs_tree.iqm_gap == pytest.approx(_iqm(tree[:, :3]), rel=1e-12)
    e = sample_efficiency(reports, [c], RESAMPLES)["ppo_residual"]
    assert e["steps"] == [0, 1000, 2000]
    for j in range(3):
        assert e["iqm"][j] == pytest.approx(_iqm(curves[:, :, j]), rel=1e-12)
        assert e["ci95"][j][0] <= e["iqm"][j] <= e["ci95"][j][1]


def test_sample_efficiency_meets_budgets_that_differ_by_task_at_common_steps():
    """A task trained twice as long (points at 0, 2000, .., 8000 against 0, 1000, .., 4000)
    enters the IQM along training at the steps both grids have, each run's own point there."""
    rng = np.random.default_rng(5)
    curves = rng.normal(0.0, 10.0, size=(3, 2, 5))
    reports = []
    for t, task in enumerate(["short", "long"]):
        agents = []
        for s in range(3):
            a = _agent(task, "td3_lagrangian", s, float(curves[s, t, -1]), None,
                       [float(v) for v in curves[s, t]])  # fmt: skip
            if task == "long":
                a.run.learning_curve = [SimpleNamespace(timesteps=2000 * j) for j in range(5)]
            agents.append(a)
        reports.append(SimpleNamespace(env_id=task, agents=agents))
    (c,) = across_tasks(reports, ["td3_lagrangian"], RESAMPLES)
    e = sample_efficiency(reports, [c], RESAMPLES)["td3_lagrangian"]
    assert e["steps"] == [0, 2000, 4000]
    for k, (j_short, j_long) in enumerate([(0, 0), (2, 1), (4, 2)]):
        grid = np.stack([curves[:, 0, j_short], curves[:, 1, j_long]], axis=1)
        assert e["iqm"][k] == pytest.approx(_iqm(grid), rel=1e-12)


def test_point_gap_is_the_paired_gaps_point_estimate():
    """A learning-curve point holds only its mean cost and violation frequency; its gap is the
    point estimate of paired_curve_gap on the same episodes (25 seeded episodes, 5 levels);
    the worst value with a diverged episode or above the curve's range, and against the
    strictest level below it."""
    rng = np.random.default_rng(3)
    E, xis = 25, (0.5, 0.7, 0.85, 0.9, 0.95)
    viol = np.clip(np.array([[0.5 - 0.08 * i] for i in range(5)]) + rng.normal(0, 0.05, (5, E)),
                   0, 1)  # fmt: skip
    cost = np.array([[100.0 + 30 * i] for i in range(5)]) + rng.normal(0, 5.0, (5, E))
    curve = ReferenceCurve("SDJLS-Solar-v0", xis, "individual", E, 0, 30, cost, viol,
                           np.zeros(5, dtype=int))  # fmt: skip
    costs, viols = rng.normal(150.0, 5.0, E), np.clip(rng.normal(0.3, 0.05, E), 0, 1)
    paired = paired_curve_gap(costs, viols, cost, viol, xis, resamples=50)
    assert point_gap(costs.mean(), viols.mean(), 0, curve) == pytest.approx(paired.relative,
                                                                             rel=1e-9)  # fmt: skip
    assert point_gap(costs.mean(), viols.mean(), 1, curve) == WORST_GAP  # a diverged episode
    assert point_gap(costs.mean(), viol.mean(axis=1).max() + 0.01, 0, curve) == WORST_GAP
    safest = int(np.argmin(viol.mean(axis=1)))  # safer than the curve: against that level
    strict = cost[safest].mean()
    assert point_gap(costs.mean(), viol.mean(axis=1).min() - 0.01, 0, curve) == pytest.approx(
        100.0 * (costs.mean() - strict) / strict
    )
