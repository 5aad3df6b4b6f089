"""benchmarks.core.stats against scipy's own implementations of the same statistics (issue 32:
"hand-written where a library does it"). The hand formulas stay (see the comments in
benchmarks/stats.py); these tests pin them to scipy on many inputs, the extremes included."""

import numpy as np
import pytest
from scipy import stats

from benchmarks.core.stats import two_proportion_p, wilson


def _pairs() -> list[tuple[int, int]]:
    """(k, n): k = 0, 1, 2, n/3, n/2, n-2, n-1, n for n from 1 to 2**62, and 500 pairs drawn
    with seed 0 (n log-uniform up to 1e9, k uniform in 0..n)."""
    out: set[tuple[int, int]] = set()
    for n in (1, 2, 3, 5, 10, 20, 100, 1000, 2000, 20_000, 40_000, 10**6, 10**9, 10**12, 10**15,
              10**18, 2**62):  # fmt: skip
        out.update((k, n) for k in (0, 1, 2, n // 3, n // 2, n - 2, n - 1, n) if 0 <= k <= n)
    rng = np.random.default_rng(0)
    for _ in range(500):
        n = int(rng.integers(1, 10 ** int(rng.integers(1, 10))))
        out.add((int(rng.integers(0, n + 1)), n))
    return sorted(out)


def test_wilson_matches_scipy_binomtest_to_1e_12_relative():
    """~580 (k, n) pairs, k = 0 and k = n, n = 1 and n up to 2**62 included: the hand formula
    and scipy.stats.binomtest(k, n).proportion_ci(method="wilson") agree to 1e-12 relative
    (measured: within 6e-15), with exactly 0 at k = 0 and exactly 1 at k = n."""
    pairs = _pairs()
    assert len(pairs) > 550
    for k, n in pairs:
        ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
        lo, hi = wilson(k, n)
        assert lo == pytest.approx(ci.low, rel=1e-12, abs=0.0), (k, n)
        assert hi == pytest.approx(ci.high, rel=1e-12, abs=0.0), (k, n)
        if k == 0:
            assert lo == 0.0
        if k == n:
            assert hi == 1.0


def test_wilson_of_an_array_is_wilson_of_each_entry():
    """The array path (the per-step intervals of benchmarks.paper.reproduce) gives, entry by
    entry, the scalar path's numbers, exactly: n = 2000 and every k in 0..2000."""
    ks = np.arange(2001)
    lo, hi = wilson(ks, 2000)
    assert lo.shape == hi.shape == ks.shape
    for k in (0, 1, 7, 999, 1000, 1999, 2000):
        assert (lo[k], hi[k]) == wilson(int(k), 2000)


def _two_sided_chi2(s1: int, n1: int, s2: int, n2: int) -> float:
    table = np.array([[s1, n1 - s1], [s2, n2 - s2]])
    return float(stats.chi2_contingency(table, correction=False).pvalue)


def test_two_proportion_p_matches_scipy_chi2_contingency():
    """The pooled z-test is the uncorrected chi-square test of the 2x2 table, one-sided: p is
    half scipy's two-sided p-value where p1 > p2 and 1 minus half of it where p1 < p2.
    500 tables drawn with seed 0 (n up to 1e7) plus hand-picked extremes (n = 1, a 1e9 table,
    p-values down to 1e-200); chi2 squares z, so the agreement is 1e-9 relative (measured:
    about 1e-12), not the last bits. Tables with a zero pooled variance are left out (scipy
    refuses them; two_proportion_p answers 0 or 1 there)."""
    rng = np.random.default_rng(0)
    cases = [(1, 1, 0, 1), (3, 10, 1, 10), (1, 2, 0, 2), (500, 1000, 400, 1000),
             (400, 1000, 500, 1000), (10**9, 2 * 10**9, 10**9 - 10**5, 2 * 10**9),
             (9000, 10_000, 1000, 10_000)]  # fmt: skip
    for _ in range(500):
        n1, n2 = (int(rng.integers(1, 10 ** int(rng.integers(1, 8)))) for _ in range(2))
        cases.append((int(rng.integers(0, n1 + 1)), n1, int(rng.integers(0, n2 + 1)), n2))
    checked = 0
    for s1, n1, s2, n2 in cases:
        if s1 + s2 in (0, n1 + n2) or s1 * n2 == s2 * n1:
            continue
        two_sided = _two_sided_chi2(s1, n1, s2, n2)
        expected = two_sided / 2 if s1 * n2 > s2 * n1 else 1 - two_sided / 2
        assert two_proportion_p(s1, n1, s2, n2) == pytest.approx(expected, rel=1e-9, abs=0.0)
        checked += 1
    assert checked > 400
    assert two_proportion_p(9000, 10_000, 1000, 10_000) < 1e-200  # a far tail, still relative
