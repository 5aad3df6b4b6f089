"""The statistics every benchmark report uses: intervals, tests, paired gaps, curve flatness.

* :func:`wilson`, :func:`mean_ci`: 95% Wilson and Student-t intervals;
* :func:`two_proportion_p`, :func:`format_p`: a one-sided test of two frequencies;
* :func:`efficient_points`: the points of a cost-violation curve that no other point beats on
  both (its efficient frontier, which the gaps are measured against);
* :func:`paired_curve_gap`: a controller's cost against a cost-violation curve at its own
  violation frequency, paired over common episodes, with a bootstrap interval;
* :func:`paired_difference`: the mean paired cost difference of two controllers, bootstrapped;
* :func:`curve_status`: whether a learning curve has flattened (two windows compared);
* :func:`interval_check`: how far per-step Wilson intervals can be trusted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

__all__ = [
    "EpisodeStatistics",
    "BOOTSTRAP_RESAMPLES",
    "BOOTSTRAP_SEED",
    "FLAT_TOL",
    "CurveGap",
    "CurveStatus",
    "IntervalCheck",
    "curve_status",
    "efficient_points",
    "format_p",
    "interval_check",
    "mean_ci",
    "paired_curve_gap",
    "paired_difference",
    "two_proportion_p",
    "wilson",
]


def wilson(successes: int | np.ndarray, trials: int, confidence: float = 0.95) -> tuple:
    """Wilson score interval for a binomial proportion; returns ``(low, high)``."""
    # By hand, not scipy.stats.binomtest(k, n).proportion_ci(method="wilson"): the two agree to
    # 6e-15 relative (tests/test_stats_scipy.py) but not bit for bit (34 of the 99 full-precision
    # intervals of results/rl/summary.json would change in their last digits), and binomtest
    # takes one k at a time (about 1.3 ms each: it also computes an exact p-value) where this
    # takes the arrays of per-step counts at once.
    z = stats.norm.ppf(0.5 + confidence / 2)
    s = np.asarray(successes, dtype=np.float64)
    phat = s / trials
    denom = 1 + z**2 / trials
    center = (phat + z**2 / (2 * trials)) / denom
    half = z * np.sqrt(phat * (1 - phat) / trials + z**2 / (4 * trials**2)) / denom
    # the exact limits lie in [0, 1], with 0 at phat = 0 and 1 at phat = 1; round-off misses both
    lo = np.where(s <= 0, 0.0, np.clip(center - half, 0.0, 1.0))
    hi = np.where(s >= trials, 1.0, np.clip(center + half, 0.0, 1.0))
    return (float(lo), float(hi)) if lo.ndim == 0 else (lo, hi)


def mean_ci(
    values: np.ndarray, confidence: float = 0.95, floor: float | None = None
) -> tuple[float, float, float]:
    """Mean and Student-t interval ``(mean, low, high)`` of i.i.d. samples.

    ``floor``: a value the mean cannot be below (0 for a cost). The interval is cut there: on
    heavy-tailed samples (diverging episodes, three seeds) the t interval reaches below it, and
    cutting off impossible values keeps the coverage as it is.
    """
    values = np.asarray(values, dtype=np.float64)
    if values.size < 2:
        raise ValueError(
            f"values has {values.size} sample(s); a Student-t interval needs at least 2"
        )
    mean = float(values.mean())
    half = float(
        stats.t.ppf(0.5 + confidence / 2, values.size - 1)
        * values.std(ddof=1)
        / np.sqrt(values.size)
    )
    low = mean - half if floor is None else max(mean - half, float(floor))
    return mean, low, mean + half


def two_proportion_p(s1: int, n1: int, s2: int, n2: int) -> float:
    """One-sided p-value of H0: p1 <= p2 against p1 > p2 (pooled z-test)."""
    # scipy has no pooled z-test of two proportions; chi2_contingency(correction=False) is the
    # same test two-sided, through z**2 (agreement 1e-12 relative, tests/test_stats_scipy.py)
    p = (s1 + s2) / (n1 + n2)
    se = np.sqrt(p * (1 - p) * (1 / n1 + 1 / n2))
    return float(stats.norm.sf((s1 / n1 - s2 / n2) / se)) if se > 0 else float(s1 / n1 <= s2 / n2)


def format_p(p: float) -> str:
    """A p-value for a report; one that underflows the float range reads ``p < 1e-300``."""
    return "p < 1e-300" if p < 1e-300 else f"p = {p:.2g}"


#: Bootstrap resamples of the episodes behind each paired gap, and the seed that draws them
#: (the same resamples for every controller scored on the same number of episodes).
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0


@dataclass(frozen=True, kw_only=True)
class EpisodeStatistics:
    """A policy's statistics over its evaluation episodes, as every report states them: the
    episodes, the mean episode cost with its 95% Student-t interval and the median, the
    violation frequency with its 95% Wilson interval, the diverged episodes. A report's record
    of one controller or run extends it (keyword fields)."""

    episodes: int
    cost_mean: float
    cost_ci95: tuple[float, float]
    cost_median: float
    violation: float
    violation_wilson95: tuple[float, float]
    diverged: int


@dataclass(frozen=True)
class CurveGap:
    """A controller against a cost-violation curve (see :func:`paired_curve_gap`).

    Attributes
    ----------
    mean : float
        Its mean episode cost minus the curve's at its violation frequency (negative: cheaper).
    ci95 : (float, float)
        95% percentile-bootstrap interval of ``mean`` over episodes.
    curve_cost : float
        The curve's cost at ``violation``.
    violation : float
        The controller's per-step violation frequency.
    xi : float or None
        The curve's parameter interpolated at ``violation`` (the level ``xi`` of a receding-
        horizon controller that would violate as often), or None without the points' ``xis``.
    relative : float or None
        ``mean`` in percent of ``curve_cost`` (negative: cheaper than the curve); None where
        the curve's cost is not positive.
    relative_ci95 : (float, float) or None
        ``ci95`` in percent of ``curve_cost`` (the curve's cost at the point estimate: a
        resample's own curve cost can be extrapolated to zero or below where its frequency
        leaves the curve's range, so the ratio is not resampled).
    """

    mean: float
    ci95: tuple[float, float]
    curve_cost: float
    violation: float
    xi: float | None = None
    relative: float | None = None
    relative_ci95: tuple[float, float] | None = None

    def percent(self) -> tuple[float, tuple[float, float]]:
        """``relative`` and ``relative_ci95``; a ValueError where they are None (the curve's
        cost at ``violation`` is not positive, so there is no percentage to report)."""
        if self.relative is None or self.relative_ci95 is None:
            raise ValueError(
                f"curve_cost = {self.curve_cost!r}; expected a positive cost for a gap in percent"
            )
        return self.relative, self.relative_ci95


def efficient_points(violations: np.ndarray, costs: np.ndarray) -> np.ndarray:
    """The indices of a curve's efficient points, in order of violation frequency.

    A point is dropped when another point has a violation frequency and a mean cost no larger and
    one of them smaller: the controller's family reaches both at once with that other level, so a
    gap measured against the dropped point would credit a controller with beating a level nobody
    would choose. (At high ``xi`` a receding-horizon controller can pay for its slacks with both:
    the generated task's 3-step tree at xi 0.99 costs 5.5x its cost at 0.97 and violates more.)
    Points that tie on both are kept. On the efficient points, cost falls strictly as the
    violation frequency grows.

    Parameters
    ----------
    violations, costs : (P,) arrays
        Each point's violation frequency and mean cost.
    """
    v = np.asarray(violations, dtype=np.float64)
    c = np.asarray(costs, dtype=np.float64)
    if v.ndim != 1 or v.shape != c.shape or v.size == 0:
        raise ValueError(
            f"violations {v.shape} and costs {c.shape}: expected two non-empty (P,) arrays"
        )
    if not (np.all(np.isfinite(v)) and not np.any(np.isnan(c)) and np.all(c > -np.inf)):
        raise ValueError(
            f"violations {v} and costs {c}: expected finite frequencies and costs that are "
            "numbers (+inf allowed: a level whose costs overflowed, never efficient next to a "
            "finite one)"
        )
    no_worse = (v[None, :] <= v[:, None]) & (c[None, :] <= c[:, None])  # [i, j]: j <= i on both
    better = (v[None, :] < v[:, None]) | (c[None, :] < c[:, None])
    dominated = np.any(no_worse & better, axis=1)
    keep = np.flatnonzero(~dominated)
    return keep[np.argsort(v[keep], kind="stable")]


def paired_curve_gap(
    costs: np.ndarray,
    violations: np.ndarray,
    curve_costs: np.ndarray,
    curve_violations: np.ndarray,
    curve_xis: Sequence[float] | None = None,
    resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> CurveGap | None:
    """Cost minus a curve's at the controller's violation frequency, paired over the episodes.

    The curve is a set of ``P`` controllers (e.g. the receding-horizon controller over a sweep of
    ``xi``) scored on the same ``E`` episodes (the same noise) as the controller, linear between
    the two points whose violation frequencies bracket the controller's. Only the curve's
    efficient points count (:func:`efficient_points`, on the means over all ``E`` episodes): a
    point that another beats on both cost and violation frequency is left out, and the range is
    that of the efficient points.

    Parameters
    ----------
    costs, violations : (E,) arrays
        The controller's cost and share of violated steps on each episode.
    curve_costs, curve_violations : (P, E) arrays
        The same for each point of the curve, P >= 2.
    curve_xis : (P,) sequence, optional
        Each point's parameter, for :attr:`CurveGap.xi`.
    resamples, seed
        Bootstrap resamples of the episodes and their seed.

    Returns
    -------
    CurveGap or None
        None where the controller's frequency lies outside the curve's range.

    Notes
    -----
    The 95% interval is a percentile bootstrap over episodes: each resample recomputes the
    controller's cost and frequency and every point's cost and frequency on the same resampled
    episodes, and interpolates anew (linearly extrapolated from the end segment where a
    resample's frequency leaves the curve's range). So the interval covers the sampling error of
    the frequencies times the curve's slope as well as the cost's; pairing removes the episode-to-
    episode spread the controller and the curve share.
    """
    costs, violations, c_cost, c_viol = _checked_curve_data(
        costs, violations, curve_costs, curve_violations, curve_xis
    )
    keep = _kept_points(c_cost, c_viol)
    c_cost, c_viol = c_cost[keep], c_viol[keep]
    if curve_xis is not None:
        curve_xis = [curve_xis[i] for i in keep]
    E = costs.size
    (gap,), (ref,), (v,), (order,), (j,), (w,) = _gaps(
        np.full((1, E), 1.0 / E), costs, violations, c_cost, c_viol
    )
    point_vs = c_viol.mean(axis=1)
    tol = 1e-12 * max(1.0, float(np.max(np.abs(point_vs))))  # v and point_vs round differently
    if not point_vs.min() - tol <= v <= point_vs.max() + tol:
        return None
    xi = None
    if curve_xis is not None:
        xis = np.asarray(curve_xis, dtype=np.float64)[order]
        xi = float(w * xis[j] + (1 - w) * xis[j + 1])
    rng = np.random.default_rng(seed)
    weights = rng.multinomial(E, np.full(E, 1.0 / E), size=resamples) / E
    boot = _gaps(weights, costs, violations, c_cost, c_viol)[0]
    lo, hi = np.percentile(boot, [2.5, 97.5])
    relative = relative_ci = None
    if ref > 0:  # costs are >= 0: only an all-zero curve fails this
        relative = float(100.0 * gap / ref)
        relative_ci = (float(100.0 * lo / ref), float(100.0 * hi / ref))
    return CurveGap(
        float(gap), (float(lo), float(hi)), float(ref), float(v), xi, relative, relative_ci
    )


def _checked_curve_data(
    costs: np.ndarray,
    violations: np.ndarray,
    curve_costs: np.ndarray,
    curve_violations: np.ndarray,
    curve_xis: Sequence[float] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`paired_curve_gap`'s arrays as float64, their shapes checked: the controller's (E,)
    and the curve's (P, E), P >= 2, with P entries of ``curve_xis``."""
    costs = np.asarray(costs, dtype=np.float64)
    violations = np.asarray(violations, dtype=np.float64)
    if costs.shape != violations.shape or costs.ndim != 1 or costs.size < 2:
        raise ValueError(
            f"costs {costs.shape} and violations {violations.shape}: expected two arrays of the "
            "same length E >= 2 (one entry per evaluation episode)"
        )
    c_cost = np.asarray(curve_costs, dtype=np.float64)
    c_viol = np.asarray(curve_violations, dtype=np.float64)
    if c_cost.ndim != 2 or c_cost.shape != c_viol.shape:
        raise ValueError(
            f"curve_costs {c_cost.shape} and curve_violations {c_viol.shape}: expected two "
            "(P, E) arrays"
        )
    if c_cost.shape[1] != costs.size or c_cost.shape[0] < 2:
        raise ValueError(
            f"the curve has {c_cost.shape[0]} point(s) on {c_cost.shape[1]} episodes; expected at "
            f"least 2 points on the controller's {costs.size} episodes"
        )
    if curve_xis is not None and len(curve_xis) != c_cost.shape[0]:
        raise ValueError(f"curve_xis has {len(curve_xis)} entries; expected {c_cost.shape[0]}")
    return costs, violations, c_cost, c_viol


def _kept_points(c_cost: np.ndarray, c_viol: np.ndarray) -> np.ndarray:
    """The indices of the curve's efficient points (at least two entries)."""
    # in the curve's own order: the resamples sort by violation anyway, and exact ties there
    # (discrete frequencies) break by this order, as they did before points were dropped
    keep = np.sort(efficient_points(c_viol.mean(axis=1), c_cost.mean(axis=1)))
    if keep.size == 1:  # one point beats all others: the curve is that point (twice)
        keep = np.repeat(keep, 2)
    return keep


def _gaps(
    weights: np.ndarray,
    costs: np.ndarray,
    violations: np.ndarray,
    c_cost: np.ndarray,
    c_viol: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """Gap, curve cost, frequency, and the interpolation (order, j, w) per row of episode
    weights (B, E), for the controller's ``costs``, ``violations`` (E,) and the curve's
    ``c_cost``, ``c_viol`` (P, E)."""
    v = weights @ violations  # (B,)
    xs, ys = weights @ c_viol.T, weights @ c_cost.T  # (B, P)
    order = np.argsort(xs, axis=1, kind="stable")
    xs, ys = np.take_along_axis(xs, order, 1), np.take_along_axis(ys, order, 1)
    j = np.clip((xs < v[:, None]).sum(axis=1) - 1, 0, xs.shape[1] - 2)[:, None]
    x0, x1 = np.take_along_axis(xs, j, 1)[:, 0], np.take_along_axis(xs, j + 1, 1)[:, 0]
    y0, y1 = np.take_along_axis(ys, j, 1)[:, 0], np.take_along_axis(ys, j + 1, 1)[:, 0]
    span = x1 - x0
    w = np.where(span == 0, 1.0, (x1 - v) / np.where(span == 0, 1.0, span))
    ref = w * y0 + (1 - w) * y1  # weight w on the lower point
    mean = weights @ costs
    gap = mean - ref
    # A controller on the curve (a curve point itself) differs from it only by the order of
    # its E-term sums and the interpolation's rounding, which depend on the CPU's kernels:
    # within that bound the gap is a tie, exactly 0 (rliable's probability of improvement
    # counts exact ties as 1/2)
    bound = (
        (2 * costs.size + 4) * np.finfo(np.float64).eps * (np.abs(mean) + np.abs(y0) + np.abs(y1))
    )
    gap = np.where(np.abs(gap) <= bound, 0.0, gap)
    return gap, ref, v, order, j[:, 0], w


def paired_difference(
    a: np.ndarray, b: np.ndarray, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> tuple[float, tuple[float, float]]:
    """Mean of ``a - b`` over common episodes (E,) and its 95% percentile-bootstrap interval."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 1 or a.size < 2:
        raise ValueError(
            f"a {a.shape} and b {b.shape}: expected two arrays of the same length E >= 2"
        )
    d = a - b
    # By hand, not scipy.stats.bootstrap(paired=True): scipy draws resampled indices, not these
    # multinomial weights, so every committed interval would move with the draws (the same
    # weights serve paired_curve_gap, which re-interpolates the curve on each resample)
    rng = np.random.default_rng(seed)
    boot = rng.multinomial(d.size, np.full(d.size, 1.0 / d.size), size=resamples) / d.size @ d
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return float(d.mean()), (float(lo), float(hi))


#: Flatness test of the learning curves (:func:`curve_status`): the largest changes between the
#: last 30% of training and the 30% before it that still count as flat.
FLAT_TOL: dict[str, float] = {"cost_rel": 0.10, "violation": 0.02, "diverged": 0.05}


@dataclass(frozen=True)
class CurveStatus:
    """The flatness test of one configuration's learning curves (seeds averaged)."""

    algo: str
    variant: str
    timesteps: int
    episodes_per_point: int
    late_window: tuple[int, int]
    earlier_window: tuple[int, int]
    violation_late: float
    diverged_share_late: float
    median_episode_diverges: bool
    cost_rel_change: float | None
    violation_change: float
    diverged_share_change: float
    flat: bool


def curve_status(runs: Sequence[Any]) -> list[CurveStatus]:
    """Has the learning curve flattened? Per (algo, variant), seeds averaged.

    ``runs`` are records with ``algo``, ``variant``, ``curve_episodes`` and ``learning_curve``
    (points with ``timesteps``, ``episode_cost_median``, ``violation``, ``diverged``).

    The evaluation points after 70% of training (the *late window*; 80%, 90% and 100% with 10
    points) are averaged and compared with as many points just before them (the *earlier
    window*). Windows rather than single points: one point is 100 episodes per seed, and its
    violation frequency alone moves by a few hundredths between neighbouring points of a curve
    that has stopped changing.

    Flat when, between the windows, the violation frequency changes by less than 0.02, the share
    of diverged evaluation episodes by less than 0.05, and the median episode cost by less than
    10% of the late window's (:data:`FLAT_TOL`). The cost condition applies only if the median
    evaluation episode does not diverge (in every seed, less than half the episodes diverge at
    every point of both windows): the median cost of a diverging episode measures how far the
    state ran off, not the policy's quality. ``cost_rel_change`` is then None.
    """
    groups: dict[tuple[str, str], list[Any]] = {}
    for r in runs:
        groups.setdefault((r.algo, r.variant), []).append(r)
    out = []
    for (algo, variant), rs in groups.items():
        usable = [r for r in rs if len(r.learning_curve) >= 3]
        if not usable:
            continue
        n = min(len(r.learning_curve) for r in usable)
        curves = [r.learning_curve[:n] for r in usable]
        episodes = [r.curve_episodes for r in usable]
        cost = np.mean([[p.episode_cost_median for p in c] for c in curves], axis=0)
        viol = np.mean([[p.violation for p in c] for c in curves], axis=0)
        div_seeds = np.array(
            [[p.diverged / e for p in c] for c, e in zip(curves, episodes, strict=True)]
        )  # (seeds, points)
        div = div_seeds.mean(axis=0)
        steps = np.array([p.timesteps for p in curves[0]])
        # the earlier window must not reach the first point (the untrained policy)
        width = max(1, min(int(np.sum(steps > 0.7 * steps[-1])), (n - 1) // 2))
        late = np.arange(n - width, n)
        early = np.arange(n - 2 * width, n - width)
        window = np.concatenate([early, late])
        dv = float(abs(viol[late].mean() - viol[early].mean()))
        dd = float(abs(div[late].mean() - div[early].mean()))
        # per seed: the seeds' medians are averaged, and one diverging median swamps the rest
        median_diverges = bool(np.any(div_seeds[:, window] >= 0.5))
        dc = None
        if not median_diverges:
            dc = float(
                abs(cost[late].mean() - cost[early].mean()) / max(abs(cost[late].mean()), 1e-12)
            )
        flat = dv < FLAT_TOL["violation"] and dd < FLAT_TOL["diverged"]
        if dc is not None:
            flat = flat and dc < FLAT_TOL["cost_rel"]
        out.append(
            CurveStatus(
                algo=algo,
                variant=variant,
                timesteps=int(steps[-1]),
                episodes_per_point=int(min(episodes)),
                late_window=(int(steps[late[0]]), int(steps[late[-1]])),
                earlier_window=(int(steps[early[0]]), int(steps[early[-1]])),
                violation_late=float(viol[late].mean()),
                diverged_share_late=float(div[late].mean()),
                median_episode_diverges=median_diverges,
                cost_rel_change=dc,
                violation_change=dv,
                diverged_share_change=dd,
                flat=bool(flat),
            )
        )
    return out


@dataclass(frozen=True)
class IntervalCheck:
    """The widest ratio of the episode interval's width to the Wilson interval's, in one group."""

    rows: int
    max_ratio: float
    name: str


def interval_check(
    rows: Sequence[tuple[str, Any]],
) -> dict[str, IntervalCheck | None] | None:
    """How far the per-step Wilson intervals can be trusted.

    ``rows`` are ``(name, score)`` pairs of single policies, each score with
    ``violation_wilson95``, ``violation_episode_t95`` (a Student-t interval over the episodes'
    shares of violated steps, which allows for dependence between the steps of an episode) and
    ``diverged``. Returns the largest ratio of the two widths among the rows with no diverged
    episode (``"stable"``) and among those with one (``"diverging"``), a part None where no row
    qualifies; None if no row has a Wilson interval of positive width.
    """
    ratios: dict[str, list[tuple[float, str]]] = {"stable": [], "diverging": []}
    for name, s in rows:
        wilson_width = s.violation_wilson95[1] - s.violation_wilson95[0]
        if wilson_width <= 0:
            continue
        ratio = (s.violation_episode_t95[1] - s.violation_episode_t95[0]) / wilson_width
        ratios["diverging" if s.diverged else "stable"].append((ratio, name))
    if not any(ratios.values()):
        return None
    return {
        part: IntervalCheck(len(rs), max(rs)[0], max(rs)[1]) if rs else None
        for part, rs in ratios.items()
    }
