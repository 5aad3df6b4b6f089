"""``benchmarks.core.stats``: the paired gap to a curve, paired differences, the flatness test of the
learning curves and the check of the Wilson intervals (synthetic data with known answers)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.core.stats import (
    curve_status,
    format_p,
    interval_check,
    paired_curve_gap,
    paired_difference,
    two_proportion_p,
)


def _curve(points):
    """``(costs (P, E), violations (P, E))`` of curve points ``(v, costs)``: every episode's
    violated share is ``v``."""
    costs = np.stack([np.asarray(c, dtype=float) for _, c in points])
    viols = np.stack([np.full(costs.shape[1], v) for v, _ in points])
    return costs, viols


def test_paired_curve_gap_interpolates_episode_by_episode():
    rng = np.random.default_rng(5)
    noise = rng.lognormal(8.0, 0.5, 400)  # the spread every controller shares on an episode
    costs, viols = _curve([(0.5, noise + 100), (0.2, noise + 400), (0.3, noise + 250)])
    xis = (0.5, 0.85, 0.7)
    # at v = 0.25, halfway between 0.2 (cost + 400) and 0.3 (+ 250): the curve is noise + 325
    at = np.full(400, 0.25)
    g = paired_curve_gap(noise + 300 + rng.normal(0, 1, 400), at, costs, viols, xis)
    assert g.curve_cost == pytest.approx(float(np.mean(noise)) + 325)
    assert g.violation == pytest.approx(0.25)
    assert g.xi == pytest.approx((0.85 + 0.7) / 2)  # halfway in xi too
    assert g.ci95[0] < -25 < g.ci95[1] and g.ci95[1] - g.ci95[0] < 1.0
    # unpaired, the shared spread would swamp the 25: the paired interval is what resolves it
    assert 2 * 1.96 * np.std(noise) / np.sqrt(400) > 50
    at_point = paired_curve_gap(noise + 250, np.full(400, 0.3), costs, viols, xis)
    assert at_point.mean == pytest.approx(0.0, abs=1e-9) and at_point.xi == pytest.approx(0.7)
    assert paired_curve_gap(noise, np.full(400, 0.6), costs, viols) is None  # outside 0.2..0.5
    assert paired_curve_gap(noise, np.full(400, 0.1), costs, viols) is None
    # each end point of the curve is inside its own range (the two means round differently)
    assert paired_curve_gap(noise + 100, np.full(400, 0.5), costs, viols).mean == pytest.approx(0)
    # the same resamples every call: the interval is reproducible
    assert paired_curve_gap(noise + 300, at, costs, viols) == paired_curve_gap(
        noise + 300, at, costs, viols
    )


def test_paired_curve_gap_interval_covers_the_error_of_the_violation_frequency():
    """On a steep segment of the curve, the sampling error of the agent's violation frequency
    moves the curve's cost at that frequency; the bootstrap interval must be as wide as that.
    E = 1000 episodes of 20 steps, violated share binomial(20, 0.25) / 20; 2000 resamples."""
    E = 1000
    rng = np.random.default_rng(11)
    base = np.full(E, 5000.0)  # costs without episode noise: only the frequency's error remains
    slope = -20000.0  # cost per unit of violation frequency between 0.2 and 0.3
    costs, viols = _curve([(0.2, base), (0.3, base + 0.1 * slope)])
    viol = rng.binomial(20, 0.25, E) / 20
    g = paired_curve_gap(base + 0.05 * slope, viol, costs, viols)
    # the gap is the agent's cost minus the curve at the agent's own (sample) frequency
    assert g.mean == pytest.approx(slope * (0.25 - viol.mean()), abs=1e-6)
    expected_half = 1.96 * abs(slope) * viol.std(ddof=1) / np.sqrt(E)  # about 38
    half = (g.ci95[1] - g.ci95[0]) / 2
    assert 0.85 * expected_half < half < 1.15 * expected_half
    assert g.ci95[0] < g.mean < g.ci95[1]


def test_paired_curve_gap_rejects_mismatched_inputs():
    costs, viols = _curve([(0.2, np.ones(10)), (0.3, np.ones(10))])
    with pytest.raises(ValueError, match="same length"):
        paired_curve_gap(np.ones(10), np.ones(9), costs, viols)
    with pytest.raises(ValueError, match="controller's 8 episodes"):
        paired_curve_gap(np.ones(8), np.full(8, 0.25), costs, viols)
    with pytest.raises(ValueError, match="at least 2 points"):
        paired_curve_gap(np.ones(10), np.full(10, 0.25), costs[:1], viols[:1])
    with pytest.raises(ValueError, match="curve_xis has 3 entries"):
        paired_curve_gap(np.ones(10), np.full(10, 0.25), costs, viols, (0.1, 0.2, 0.3))


def test_paired_difference_resolves_what_unpaired_intervals_cannot():
    """400 episodes sharing a lognormal spread; b costs 5 more on every episode (+ N(0, 1)):
    the paired 95% interval is about +-0.1 wide around -5."""
    rng = np.random.default_rng(3)
    shared = rng.lognormal(8.0, 0.5, 400)
    mean, (lo, hi) = paired_difference(shared, shared + 5 + rng.normal(0, 1, 400))
    assert lo < mean < hi and hi - lo < 0.5 and lo < -5 + 0.3 and hi > -5 - 0.3
    with pytest.raises(ValueError, match="same length"):
        paired_difference(np.ones(3), np.ones(4))


def test_two_proportion_test_and_p_values():
    assert two_proportion_p(60, 100, 40, 100) < 0.01 < two_proportion_p(40, 100, 60, 100)
    assert format_p(0.0) == "p < 1e-300" and format_p(0.012) == "p = 0.012"


# ------------------------------------------------------------------ the flatness test
def _run(algo, variant, seed, cost, violation, diverged, episodes=100, total=1000):
    """A synthetic run record with a learning curve of ``len(cost)`` points."""
    n = len(cost)
    curve = [
        SimpleNamespace(
            timesteps=round(total * i / (n - 1)), episode_cost_median=c, violation=v, diverged=d
        )
        for i, (c, v, d) in enumerate(zip(cost, violation, diverged, strict=True))
    ]
    return SimpleNamespace(
        algo=algo, variant=variant, seed=seed, curve_episodes=episodes, learning_curve=curve
    )


def _status(runs):
    return {(s.algo, s.variant): s for s in curve_status(runs)}


def test_curve_status_windows():
    """11 points (0%, 10%, ..., 100%): the late window is 80-100%, the earlier one 50-70%."""
    flat_cost = [9e3, 6e3, 5e3, 5e3, 5e3, 5100, 4900, 5000, 5050, 4950, 5000]
    flat_v = [0.9, 0.5, 0.3, 0.2, 0.2, 0.21, 0.19, 0.20, 0.19, 0.21, 0.20]
    falling_v = [0.9, 0.5, 0.3, 0.25, 0.24, 0.23, 0.22, 0.21, 0.19, 0.18, 0.17]
    falling_c = [9e3, 8e3, 7e3, 6e3, 6e3, 6e3, 6e3, 6e3, 5.1e3, 5.1e3, 5.1e3]
    zero = [0] * 11
    st = _status(
        [
            _run("td3", "residual", 0, flat_cost, flat_v, zero),
            _run("td3", "beta100", 0, flat_cost, falling_v, zero),
            _run("td3", "beta1000", 0, falling_c, flat_v, zero),
        ]
    )
    s = st[("td3", "residual")]
    assert s.late_window == (800, 1000) and s.earlier_window == (500, 700)
    assert s.flat and s.cost_rel_change == pytest.approx(0.0, abs=1e-12)
    assert s.violation_change == pytest.approx(0.0, abs=1e-12)
    assert not st[("td3", "beta100")].flat
    assert st[("td3", "beta100")].violation_change == pytest.approx(0.04)
    assert not st[("td3", "beta1000")].flat
    assert st[("td3", "beta1000")].cost_rel_change == pytest.approx(0.9e3 / 5.1e3)


def test_curve_status_averages_windows_and_seeds():
    """Noise that single points would call a change cancels in the window means; opposite
    drifts of two seeds cancel in the seed average."""
    cost = [5e3] * 11
    zero = [0] * 11
    noisy = [0.9, 0.3, 0.2, 0.2, 0.2, 0.23, 0.20, 0.17, 0.20, 0.17, 0.23]
    assert _status([_run("sac", "residual", 0, cost, noisy, zero)])[("sac", "residual")].flat
    drifting = noisy[:-1] + [0.32]  # late window 0.23 against 0.20
    assert not _status([_run("sac", "residual", 0, cost, drifting, zero)])[("sac", "residual")].flat
    up = [0.9, 0.3, 0.2, 0.2, 0.2, 0.17, 0.17, 0.17, 0.23, 0.23, 0.23]
    down = [0.9, 0.3, 0.2, 0.2, 0.2, 0.23, 0.23, 0.23, 0.17, 0.17, 0.17]
    assert not _status([_run("td3", "reward", 0, cost, up, zero)])[("td3", "reward")].flat
    both = _status(
        [_run("td3", "reward", 0, cost, up, zero), _run("td3", "reward", 1, cost, down, zero)]
    )
    assert both[("td3", "reward")].flat


def test_curve_status_ignores_the_cost_of_diverging_episodes():
    jumping = [4e11, 2e11, 1e11, 3e11, 1e11, 4e11, 1e11, 2e11, 1e11, 3e11, 4e11]
    v = [0.9] + [0.6] * 10
    steady = [100] + [60] * 10
    falling = [100, 90, 80, 75, 70, 68, 66, 64, 58, 56, 54]
    st = _status(
        [
            _run("ppo", "beta1000", 0, jumping, v, steady),
            _run("ppo", "reward", 0, jumping, v, falling),
        ]
    )
    s = st[("ppo", "beta1000")]
    assert s.median_episode_diverges and s.cost_rel_change is None and s.flat
    r = st[("ppo", "reward")]
    assert r.diverged_share_change == pytest.approx(0.10) and not r.flat
    assert r.diverged_share_late == pytest.approx(0.56)
    half = _status([_run("ppo", "beta100", 0, jumping, v, [10] * 11)])[("ppo", "beta100")]
    assert not half.median_episode_diverges and not half.flat


def test_curve_status_median_divergence_is_judged_per_seed():
    """Seeds diverging in 0.8, 0.6 and 0 of the episodes average below one half, yet two of the
    three medians are divergence magnitudes: the cost is not compared then."""
    cost = [4e11] + [3e11, 1e11] * 5
    v = [0.9] + [0.5] * 10
    runs = [
        _run("ppo", "beta100", 0, cost, v, [80] * 11),
        _run("ppo", "beta100", 1, cost, v, [60] * 11),
        _run("ppo", "beta100", 2, [500.0] * 11, v, [0] * 11),
    ]
    s = _status(runs)[("ppo", "beta100")]
    assert s.diverged_share_late == pytest.approx(140 / 300)
    assert s.median_episode_diverges and s.cost_rel_change is None


def test_curve_status_short_curves():
    """The quick run's curves (0 and three points): one point per window, never the untrained
    policy; fewer than three points are not judged."""
    st = _status([_run("ppo", "residual", 0, [9e3, 5e3, 5e3, 5e3], [1, 0.2, 0.2, 0.2], [0] * 4)])
    s = st[("ppo", "residual")]
    assert s.late_window == (1000, 1000) and s.earlier_window == (667, 667) and s.flat
    assert _status([_run("ppo", "residual", 0, [1, 2], [0, 0], [0, 0])]) == {}


# ------------------------------------------------------------------ the interval check
def _score(diverged, wilson, episode):
    return SimpleNamespace(
        diverged=diverged, violation_wilson95=wilson, violation_episode_t95=episode
    )


def test_interval_check_takes_the_widest_ratio_in_each_part():
    rows = [
        ("a", _score(0, (0.10, 0.12), (0.10, 0.122))),  # 1.1
        ("b", _score(0, (0.20, 0.22), (0.195, 0.225))),  # 1.5
        ("c", _score(3, (0.50, 0.52), (0.45, 0.57))),  # 6
        ("flat", _score(0, (1.0, 1.0), (1.0, 1.0))),  # zero Wilson width: no ratio
    ]
    check = interval_check(rows)
    assert check["stable"].rows == 2 and check["stable"].name == "b"
    assert check["stable"].max_ratio == pytest.approx(1.5)
    assert check["diverging"].rows == 1 and check["diverging"].name == "c"
    assert check["diverging"].max_ratio == pytest.approx(6.0)
    assert interval_check(rows[:2])["diverging"] is None
    assert interval_check(rows[3:]) is None


def test_paired_curve_gap_at_the_curves_end_point_is_inside_its_range():
    """A controller at the curve's riskiest point (0.7, 400 episodes) is at that point, gap 0.
    The mean over episodes and the bootstrap's weighted mean round 0.7 differently
    (0.7000000000000002 against 0.7); without a tolerance the point was called outside."""
    rng = np.random.default_rng(2)
    noise = rng.lognormal(8.0, 0.5, 400)
    costs, viols = _curve([(0.2, noise + 400), (0.7, noise)])
    g = paired_curve_gap(noise, np.full(400, 0.7), costs, viols, (0.9, 0.3))
    assert g is not None and g.mean == pytest.approx(0.0, abs=1e-9) and g.xi == pytest.approx(0.3)


def test_paired_curve_gap_of_a_curve_point_is_an_exact_tie():
    """A controller whose episode costs are a curve point's, each moved by a few units in the
    last place (the round-off of another CPU's kernels), has a gap of exactly 0 (a tie for
    rliable's probability of improvement); a difference of 1e-10 of the costs is not a tie."""
    rng = np.random.default_rng(4)
    noise = rng.lognormal(8.0, 0.5, 400)
    costs, viols = _curve([(0.2, noise + 400), (0.3, noise + 250), (0.5, noise + 100)])
    at = np.full(400, 0.3)
    moved = noise + 250
    for _ in range(3):
        moved = np.nextafter(moved, np.where(rng.random(400) < 0.5, 0.0, np.inf))
    assert not np.array_equal(moved, noise + 250)
    assert np.mean(moved) != np.mean(noise + 250)  # the plain difference is round-off, not 0
    g = paired_curve_gap(moved, at, costs, viols)
    assert g.mean == 0.0 and g.relative == 0.0
    assert paired_curve_gap(noise + 250, at, costs, viols).mean == 0.0
    off = paired_curve_gap((noise + 250) * (1 + 1e-10), at, costs, viols)
    assert off.mean == pytest.approx(1e-10 * np.mean(noise + 250), rel=1e-3)
