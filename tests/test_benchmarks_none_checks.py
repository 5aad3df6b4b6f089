"""Values typed ``X | None`` in benchmarks that must be given where they are used (issue 32,
typed end to end): a None there is refused with a ValueError naming it, where it used to be
sorted, formatted or averaged into a TypeError or a silent NaN."""

from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.core.stats import CurveGap
from benchmarks.rl.report import aggregate, curve_xi


def test_curve_xi_refuses_a_point_without_xi():
    assert curve_xi(SimpleNamespace(name="RHC", xi=0.85)) == 0.85
    with pytest.raises(ValueError, match=r"'MJLS LQ'.*xi = None"):
        curve_xi(SimpleNamespace(name="MJLS LQ", xi=None))


def test_curve_gap_percent_refuses_a_gap_without_a_percentage():
    gap = CurveGap(-5.0, (-6.0, -4.0), 75.0, 0.2, 0.8, -6.7, (-8.0, -5.3))
    assert gap.percent() == (-6.7, (-8.0, -5.3))
    no_cost = CurveGap(-5.0, (-6.0, -4.0), 0.0, 0.2)  # a curve of cost 0: no percentage
    with pytest.raises(ValueError, match=r"curve_cost = 0\.0"):
        no_cost.percent()


def _run(seed: int, final_beta: float | None) -> SimpleNamespace:
    """A scored training run of PPO lagrangian on 10 episodes of 20 steps (duck-typed)."""
    run = SimpleNamespace(algo="ppo", variant="lagrangian", final_beta=final_beta,
                          timesteps=1000, train_time_s=1.0, seed=seed)  # fmt: skip
    score = SimpleNamespace(cost_mean=10.0 + seed, cost_ci95=(9.0, 12.0), cost_median=10.0,
                            episodes=10, steps=20, violation=0.1, diverged=0,
                            decision_time_batched_s=1e-6, decision_time_single_s=1e-4)  # fmt: skip
    return SimpleNamespace(run=run, score=score)


def test_aggregate_final_beta_is_given_on_every_seed_or_on_none():
    (row,) = aggregate([_run(0, 10.0), _run(1, 30.0)])
    assert row.final_beta == pytest.approx(20.0)
    (row,) = aggregate([_run(0, None), _run(1, None)])
    assert row.final_beta is None
    for betas in ((None, 30.0), (10.0, None)):  # before: None, or a TypeError in np.mean
        with pytest.raises(ValueError, match=r"final_beta = \[.*None.*\]"):
            aggregate([_run(0, betas[0]), _run(1, betas[1])])
    assert np.isfinite(row.cost_mean)
