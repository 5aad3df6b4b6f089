"""``benchmarks.core.montecarlo.rollout``: how an episode that diverges is recorded and scored, and the
intervals of ``benchmarks.core.stats``."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import raises_naming

from benchmarks.core.montecarlo import Rollouts, rollout
from benchmarks.core.stats import mean_ci, wilson
from benchmarks.evaluate import rollout_statistics
from controllers import LinearFeedbackController
from sdjls_gym import SDJLSModel
from sdjls_gym.systems.macro import PAPER_K, macro

RUNS, T = 40, 20


class _HalfUnstable:
    """The paper's feedback on rows ``>= RUNS // 2``; ``u = 0`` (open loop) on the others.

    The open loop diverges within a few steps (the slump mode has an eigenvalue near -6),
    so the first half of the batch ends early and the second half never does.
    """

    def __init__(self, model) -> None:
        self.inner = LinearFeedbackController(model, PAPER_K)

    def act_batch(self, x, mode, k):
        u, info = self.inner.act_batch(x, mode, k)
        u = np.array(u, dtype=np.float64)
        u[: RUNS // 2] = 200.0 * np.sign(x[: RUNS // 2, 1:2] + 1e-12)  # push x2 away from 0
        return u, info


def test_a_diverged_episode_holds_its_state_and_counts_as_violated():
    model = macro()
    ro = rollout(model, _HalfUnstable(model), RUNS, T, seed=3)
    bad = np.any(np.abs(ro.x) > 1e6, axis=(1, 2))
    assert bad[: RUNS // 2].all() and not bad[RUNS // 2 :].any()
    for i in np.flatnonzero(bad):
        end = int(np.argmax(np.abs(ro.x[i, 1:]).max(axis=1) > 1e6))  # step whose x_{k+1} diverged
        assert end < T - 1, "the test needs episodes that end before the last step"
        assert not ro.ended[i, : end + 1].any() and ro.ended[i, end + 1 :].all()
        # held, not restarted: the state stays the diverged one (never back near x0 = (2, 2))
        np.testing.assert_array_equal(
            ro.x[i, end + 2 :], np.broadcast_to(ro.x[i, end + 1], (T - end - 1, 2))
        )
        assert np.all(ro.stage_cost[i, end + 1 :] == 0.0) and np.all(ro.u[i, end + 1 :] == 0.0)
        assert ro.any_violation[i, end:].all()
    assert not ro.ended[RUNS // 2 :].any()


def test_rows_that_do_not_diverge_are_unaffected():
    """Common random numbers: the stable rows match a run where no row diverges."""
    model = macro()
    ro = rollout(model, _HalfUnstable(model), RUNS, T, seed=3)
    ref = rollout(model, LinearFeedbackController(model, PAPER_K), RUNS, T, seed=3)
    half = slice(RUNS // 2, None)
    np.testing.assert_array_equal(ro.x[half], ref.x[half])
    np.testing.assert_array_equal(ro.violations[half], ref.violations[half])
    assert not ref.ended.any()


def test_rows_that_do_not_diverge_are_unaffected_with_a_random_initial_mode():
    """Autoresets draw their initial mode (mode0 a probability vector) from a stream of their
    own: the other rows' noise and modes do not depend on which rows diverged."""
    data = macro().to_dict()
    data["mode0"] = [0.5, 0.3, 0.2]
    model = SDJLSModel.from_dict(data)
    ro = rollout(model, _HalfUnstable(model), RUNS, T, seed=3)
    ref = rollout(model, LinearFeedbackController(model, PAPER_K), RUNS, T, seed=3)
    assert ro.ended[: RUNS // 2].any() and len(set(ref.mode[:, 0])) > 1
    half = slice(RUNS // 2, None)
    np.testing.assert_array_equal(ro.x[half], ref.x[half])
    np.testing.assert_array_equal(ro.mode[half], ref.mode[half])


def test_score_counts_every_step_after_divergence():
    model = macro()
    ro = rollout(model, _HalfUnstable(model), RUNS, T, seed=3)
    stats = rollout_statistics(ro, 1e6)
    assert stats["diverged"] == RUNS // 2
    # 20 stable rows as simulated, plus 20 rows violated from their divergence on
    stable = ro.any_violation[RUNS // 2 :].sum()
    ended = ro.ended[: RUNS // 2]
    before = ro.any_violation[: RUNS // 2][~ended].sum()
    assert stats["violation"] == (stable + before + ended.sum()) / (RUNS * T)
    assert ended.sum() > RUNS // 2  # most diverged rows end several steps early
    assert np.all(ro.violations[: RUNS // 2][ended])  # every row of the band, on ended steps
    assert np.isfinite(stats["cost_mean"])


def test_wilson_limits_stay_in_the_unit_interval():
    """At 0 and at n successes the limits are exactly 0 and 1 (round-off used to give 1 + 2e-16)."""
    for n in (1, 7, 200, 20000, 60000):
        assert wilson(n, n)[1] == 1.0 and wilson(0, n)[0] == 0.0
        lo, hi = wilson(np.arange(n + 1), n)
        assert np.all((0.0 <= lo) & (lo <= np.arange(n + 1) / n) & (np.arange(n + 1) / n <= hi))
        assert np.all(hi <= 1.0)
    # the textbook value for 5 of 10 (Wilson 1927; e.g. Brown, Cai and DasGupta 2001): 0.2366-0.7634
    np.testing.assert_allclose(wilson(5, 10), (0.2366, 0.7634), atol=5e-5)


def test_mean_ci_floor_cuts_only_impossible_values():
    costs = np.array([1.0, 2.0, 1e6])  # one diverging episode among three: t interval below 0
    mean, lo, hi = mean_ci(costs)
    assert lo < 0 < mean < hi
    assert mean_ci(costs, floor=0.0) == (mean, 0.0, hi)
    tame = np.array([10.0, 11.0, 12.0])
    assert mean_ci(tame, floor=0.0) == mean_ci(tame)  # nothing to cut


def test_mean_ci_needs_two_samples():
    """One sample has no spread to estimate: an error, not a zero-width interval."""
    with raises_naming(ValueError, "values", 1):  # 1 sample
        mean_ci(np.array([3.0]))
    assert mean_ci(np.array([1.0, 3.0]))[0] == 2.0


def _synthetic(violated: np.ndarray) -> Rollouts:
    """Rollouts of a stable controller whose steps are violated as ``violated`` (E, T) says."""
    runs, steps = violated.shape
    return Rollouts(
        x=np.zeros((runs, steps + 1, 2)),
        mode=np.zeros((runs, steps + 1), dtype=np.int64),
        u=np.zeros((runs, steps, 1)),
        rho=np.zeros((runs, steps)),
        J=np.zeros((runs, steps)),
        stage_cost=np.ones((runs, steps)),
        violations=np.repeat(violated[:, :, None], 2, axis=2),
        status_ok=np.ones((runs, steps), dtype=bool),
        ended=np.zeros((runs, steps), dtype=bool),
    )


def score(ro: Rollouts) -> dict:
    return rollout_statistics(ro, 1e6)


def _widths(stats: dict) -> tuple[float, float]:
    (lo, hi), (elo, ehi) = stats["violation_wilson95"], stats["violation_episode_t95"]
    assert elo <= stats["violation"] <= ehi
    assert 0.0 <= elo and ehi <= 1.0
    return hi - lo, ehi - elo


def test_episode_interval_agrees_with_wilson_only_for_independent_steps():
    """2000 episodes of 20 steps, violated with probability 0.2 (seeded). Independent steps:
    the interval over episodes has the Wilson width (the sample sd of the episodes' shares
    is within about 1.6% of its true value, so 10% is about six standard errors). Whole
    episodes violated or not: the shares vary sqrt(20) = 4.47 times as much, and so must the
    width."""
    rng = np.random.default_rng(11)
    runs, p = 2000, 0.2
    wilson_w, episode_w = _widths(score(_synthetic(rng.random((runs, T)) < p)))
    assert episode_w / wilson_w == pytest.approx(1.0, rel=0.10)
    together = np.repeat(rng.random((runs, 1)) < p, T, axis=1)
    wilson_w, episode_w = _widths(score(_synthetic(together)))
    assert episode_w / wilson_w == pytest.approx(np.sqrt(T), rel=0.10)


def test_episode_interval_at_the_ends_and_with_one_episode():
    all_violated = score(_synthetic(np.ones((5, T), dtype=bool)))
    assert all_violated["violation_episode_t95"] == (1.0, 1.0)
    assert all_violated["violation"] == 1.0
    one = np.zeros((3, T), dtype=bool)
    one[0, 0] = True  # shares 0.05, 0, 0: the t interval reaches below 0
    near_zero = score(_synthetic(one))["violation_episode_t95"]
    assert near_zero[0] == 0.0 < near_zero[1]
    with raises_naming(ValueError, "episodes", 1):  # the intervals are over episodes
        score(_synthetic(np.ones((1, T), dtype=bool)))
