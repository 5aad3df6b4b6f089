"""``benchmarks.core.stats.efficient_points``: the curve points a gap is measured against, and the
gaps that use them (paired_curve_gap, gap_reason, the learning-curve points' point_gap)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.core.frontier import WORST_GAP, ReferenceCurve, gap_reason
from benchmarks.core.stats import efficient_points, paired_curve_gap
from benchmarks.rl.suite_report import point_gap


def _dominated_by_hand(v: np.ndarray, c: np.ndarray) -> set[int]:
    """Indices i for which some j is no worse on both and better on one, by a double loop."""
    out = set()
    for i in range(v.size):
        for j in range(v.size):
            if v[j] <= v[i] and c[j] <= c[i] and (v[j] < v[i] or c[j] < c[i]):
                out.add(i)
    return out


@pytest.mark.parametrize("seed", range(20))
def test_efficient_points_against_a_double_loop(seed):
    """Random sets of 1-12 points, values on a coarse grid so that ties on one or both
    coordinates occur: the kept set is the complement of the dominated set, sorted by
    violation frequency, and on it cost falls strictly (ties on both kept, equal)."""
    rng = np.random.default_rng(seed)
    P = int(rng.integers(1, 13))
    v = rng.integers(0, 6, P) / 10.0
    c = rng.integers(0, 6, P) * 7.0
    keep = efficient_points(v, c)
    assert set(keep.tolist()) == set(range(P)) - _dominated_by_hand(v, c)
    assert keep.size >= 1
    assert np.all(np.diff(v[keep]) >= 0)
    for a, b in zip(keep[:-1], keep[1:], strict=True):
        assert (v[a] == v[b] and c[a] == c[b]) or (v[a] < v[b] and c[a] > c[b])


def test_efficient_points_rejects_bad_input():
    for v, c in [(np.zeros(3), np.zeros(2)), (np.zeros(0), np.zeros(0)),
                 (np.zeros((2, 2)), np.zeros((2, 2))), (np.array([0.1, np.nan]), np.zeros(2)),
                 (np.array([0.1, 0.2]), np.array([1.0, np.nan])),
                 (np.array([0.1, 0.2]), np.array([1.0, -np.inf]))]:  # fmt: skip
        with pytest.raises(ValueError, match="violations"):
            efficient_points(v, c)


def test_a_level_whose_cost_overflowed_is_dominated_not_an_error():
    """A mean cost of +inf (episodes whose costs overflowed) is a number: beaten by any finite
    level no riskier, kept only where nothing is as safe."""
    v = np.array([0.1, 0.2, 0.05])
    np.testing.assert_array_equal(efficient_points(v, np.array([1.0, np.inf, 3.0])), [2, 0])
    np.testing.assert_array_equal(efficient_points(v, np.array([1.0, 0.5, np.inf])), [2, 0, 1])


def _noisy_curve(rng, points, E):
    """(costs (P, E), violations (P, E)) with episode noise around each point's means."""
    costs = np.stack([c + rng.normal(0.0, 0.02 * c, E) for _, c in points])
    viols = np.stack([np.clip(v + rng.normal(0.0, 0.01, E), 0, 1) for v, _ in points])
    return costs, viols


def test_a_dominated_level_changes_no_gap():
    """The generated task's shape (300 seeded episodes): levels 0.95, 0.97 and a level 0.99
    that costs 5x more than 0.97 and violates more. A controller between 0.95 and 0.97 has the
    same gap, interval and xi with and without the 0.99 level (bit for bit: the same episodes'
    weights, the same bracketing points); without the efficient points it was interpolated
    towards 0.99's cost and read about -70%."""
    rng = np.random.default_rng(7)
    E = 300
    pts = [(0.066, 3.3), (0.0496, 9.5), (0.0538, 52.7)]
    costs, viols = _noisy_curve(rng, pts, E)
    xis = (0.95, 0.97, 0.99)
    ctrl_c = 4.0 + rng.normal(0.0, 0.1, E)
    ctrl_v = np.clip(0.06 + rng.normal(0.0, 0.01, E), 0, 1)
    full = paired_curve_gap(ctrl_c, ctrl_v, costs, viols, xis, resamples=200)
    two = paired_curve_gap(ctrl_c, ctrl_v, costs[:2], viols[:2], xis[:2], resamples=200)
    assert full == two
    # by hand: linear between the two efficient points at the controller's frequency
    v = viols.mean(axis=1)
    c = costs.mean(axis=1)
    w = (v[0] - ctrl_v.mean()) / (v[0] - v[1])
    ref = (1 - w) * c[0] + w * c[1]
    assert full.curve_cost == pytest.approx(ref, rel=1e-12)
    assert full.relative == pytest.approx(100 * (ctrl_c.mean() - ref) / ref, rel=1e-9)
    assert 0.95 < full.xi < 0.97
    assert -40.0 < full.relative < 0.0  # not the artifact of interpolating towards 52.7
    curve = ReferenceCurve("SDJLS-Random-v0", xis, "individual", E, 0, 50, costs, viols,
                           np.zeros(3, dtype=int))  # fmt: skip
    assert point_gap(ctrl_c.mean(), ctrl_v.mean(), 0, curve) == pytest.approx(full.relative,
                                                                               rel=1e-9)  # fmt: skip
    assert curve.gap(ctrl_c, ctrl_v) == paired_curve_gap(
        ctrl_c, ctrl_v, costs[:2], viols[:2], xis[:2]
    )


def test_range_and_reason_are_the_efficient_points():
    """A level riskier and costlier than every other (0.5: violation 0.3) widens no range: a
    controller at violation 0.2 is riskier than the efficient points (0.05..0.1) and has no gap,
    and the reason names the efficient range; with the costs left out the reason names all
    points' range (the older call)."""
    rng = np.random.default_rng(8)
    E = 200
    costs, viols = _noisy_curve(rng, [(0.3, 50.0), (0.1, 5.0), (0.05, 9.0)], E)
    ctrl_c, ctrl_v = np.full(E, 4.0), np.full(E, 0.2)
    assert paired_curve_gap(ctrl_c, ctrl_v, costs, viols, resamples=50) is None
    reason = gap_reason(0.2, 0, None, viols, costs)
    v = viols.mean(axis=1)
    assert f"{v[2]:.3f}..{v[1]:.3f}" in reason and "above" in reason
    assert f"{v[2]:.3f}..{v[0]:.3f}" in gap_reason(0.35, 0, None, viols)
    curve = ReferenceCurve("SDJLS-Random-v0", (0.5, 0.9, 0.95), "individual", E, 0, 50, costs,
                           viols, np.zeros(3, dtype=int))  # fmt: skip
    assert point_gap(4.0, 0.2, 0, curve) == WORST_GAP  # riskier than the curve: the worst value


def test_one_efficient_point_is_the_whole_curve():
    """A level that beats every other on both is the curve: a controller at exactly its
    frequency is compared with it, any other frequency has no gap."""
    rng = np.random.default_rng(9)
    E = 100
    noise = rng.lognormal(1.0, 0.3, E)
    costs = np.stack([noise + 1.0, noise + 3.0])
    viols = np.stack([np.full(E, 0.1), np.full(E, 0.2)])
    g = paired_curve_gap(noise, np.full(E, 0.1), costs, viols, (0.9, 0.5), resamples=50)
    assert g is not None and g.mean == pytest.approx(-1.0) and g.xi == pytest.approx(0.9)
    assert paired_curve_gap(noise, np.full(E, 0.15), costs, viols, resamples=50) is None
