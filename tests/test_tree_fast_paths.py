"""The scenario tree's fast paths of issue 29 against the plain computations they stand for.

What is checked, and against what:

* the stacked maps (:func:`controllers.kkt_maps.stacked_maps`, the exact solve of an active set
  as two matrices) against :func:`controllers.kkt.solve_stacked` and the KKT test made with them
  against the test made without, on random QPs with slacks and bounds (seeded: 40 problems,
  every active set the enumeration admits): the same acceptance, ``z`` and the multipliers to
  1e-12 of the magnitudes of their terms;
* the caches of :class:`controllers.tree_qp.TreeQP` keyed by a Hessian's token: with Hessians
  alternating under their tokens, every verification equals that of a family that never saw
  another Hessian (a stale cache entry would give another Hessian's answer);
* the warm paths of the tree (the last active set, the sets optimal before it, the repair)
  against the same tree without the warm start (DAQP at every solve), on 160 closed-loop
  states of the macro example: the same decisions and costs to 1e-9, both warm paths met;
* Newton's step on the fixed point of the region probabilities against the plain iteration
  (Aitken's extrapolation, Newton's step switched off) on the same states: the same fixed
  point to 1e-6 in ``u`` (the convergence test's tolerance on the probabilities), in at most
  as many solves, and at most two wherever the plain iteration took three;
* the earlier sets tried while they pay, and not after (a planted record of tries that never
  paid), every answer the cold solve's; ``families_built``;
* the band form of :meth:`controllers.tree_region.RegionClasses.limits` against the general
  form (every class given its rows above and below), empty intervals included.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from benchmarks.speed.measure import closed_loop_states
from controllers import RecedingHorizonController, ScenarioTreeController
from controllers.kkt import active_set_factor, check_active_set, reduce_hessian, solve_stacked
from controllers.kkt_maps import stacked_maps
from controllers.rhc import DEFAULT_OSQP_SETTINGS
from controllers.tree_qp import TreeQP
from controllers.tree_region import RegionClasses
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, macro


def _random_qp(rng: np.random.Generator, d: int, c: int, slacks: int):
    """``(P, C, pivots)``: a random Hessian that is zero on the last ``slacks`` variables (as the
    tree's slacks), ``c`` general rows, each slack in one of them with coefficient -1, and a
    bound ``z_j >= 0`` on each slack."""
    L = rng.normal(size=(d, d)) * rng.uniform(0.1, 10.0, size=d)
    P = L @ L.T
    P[d - slacks :, :] = 0.0
    P[:, d - slacks :] = 0.0
    G = rng.normal(size=(c, d))
    G[:, d - slacks :] = 0.0
    for j in range(slacks):
        G[j % c, d - slacks + j] = -1.0
    bounds = np.zeros((slacks, d))
    bounds[np.arange(slacks), d - slacks + np.arange(slacks)] = -1.0
    C = np.vstack([G, bounds])
    return P, C, ~P.any(axis=1)


def test_stacked_maps_are_the_stacked_solve():
    rng = np.random.default_rng(29)
    checked = accepted = 0
    for _ in range(40):
        d, slacks = int(rng.integers(3, 7)), int(rng.integers(0, 3))
        c = int(rng.integers(2, 6))
        P, C, pivots = _random_qp(rng, d, c, slacks)
        rows_all = range(C.shape[0])
        for size in range(0, min(d, C.shape[0]) + 1):
            for rows in itertools.combinations(rows_all, size):
                fac = active_set_factor(C, rows, pivots)
                red = None if fac is None else reduce_hessian(fac, P)
                if red is None:
                    continue
                maps = stacked_maps(fac, red, P)
                assert maps is not None
                W = rng.normal(size=(d + C.shape[0], 3)) * 10.0 ** rng.uniform(-3, 3, size=3)
                W2 = np.vstack([W, np.abs(W)])
                z2, lam2 = solve_stacked(fac, red, P, W2)
                mz2, mlam2 = solve_stacked(fac, red, P, W2, maps)
                dz, dl = z2.shape[0] // 2, lam2.shape[0] // 2
                # values to round-off of their magnitudes; magnitudes to round-off of themselves
                assert np.all(np.abs(mz2[:dz] - z2[:dz]) <= 1e-12 * (z2[dz:] + 1e-300))
                assert np.all(np.abs(mlam2[:dl] - lam2[:dl]) <= 1e-12 * (lam2[dl:] + 1e-300))
                assert np.allclose(mz2[dz:], z2[dz:], rtol=1e-12, atol=0.0)
                assert np.allclose(mlam2[dl:], lam2[dl:], rtol=1e-12, atol=0.0)
                w = W[:, 0]
                plain = check_active_set(fac, P, C, w)
                fast = check_active_set(fac, P, C, w, None, None, red, maps)
                assert (plain is None) == (fast is None)
                checked += 1
                if plain is not None:
                    accepted += 1
                    scale = np.abs(P) @ np.abs(plain) + np.abs(w[:d]) + 1e-300
                    assert np.all(np.abs(np.array(fast) - np.array(plain)) <= 1e-10 * scale)
    assert checked > 300 and accepted > 10, (checked, accepted)


def test_token_caches_never_answer_for_another_hessian():
    rng = np.random.default_rng(7)
    d, c = 6, 5
    P1, C, _ = _random_qp(rng, d, c, 2)
    P2 = P1 * np.outer(np.r_[rng.uniform(0.5, 2.0, size=d - 2), 0, 0], np.ones(d))
    P2 = 0.5 * (P2 + P2.T)
    A = C  # one-sided rows: A z <= u
    lower, upper = np.zeros(C.shape[0], bool), np.ones(C.shape[0], bool)
    cached = TreeQP(np.eye(d), A, lower, upper, DEFAULT_OSQP_SETTINGS, enumerate_all=False)
    fresh = {
        t: TreeQP(np.eye(d), A, lower, upper, DEFAULT_OSQP_SETTINGS, enumerate_all=False)
        for t in (1, 2)
    }
    for t, P in ((1, P1), (2, P2)):
        P.flags.writeable = False
        fresh[t].update_P(P)
    # a few instances met again and again (the maps are built from a pair's second test on),
    # each tested on its optimal active sets under both Hessians and on other sets
    pool = [
        np.concatenate(
            [rng.normal(size=d - 2) * 3.0, rng.uniform(1.0, 5.0, size=2)]  # slacks: a cost
            + [rng.uniform(0.1, 2.0, size=c), np.zeros(2)]
        )
        for _ in range(6)
    ]
    optimal = {
        (t, i): fresh[t].solve(w, warm=False).rows for t in (1, 2) for i, w in enumerate(pool)
    }
    sets = [rows for size in range(3) for rows in itertools.combinations(range(C.shape[0]), size)]
    same = differ = 0
    for step in range(120):
        t, i = 1 + step % 2, (step // 2) % len(pool)
        cached.update_P(P1 if t == 1 else P2, t)
        w = pool[i]
        for rows in [optimal[(1, i)], optimal[(2, i)], *sets[step % 5 :: 5]]:
            a, b = cached.verify(rows, w), fresh[t].verify(rows, w)
            assert (a is None) == (b is None)
            if a is not None:
                assert np.allclose(a, b, rtol=1e-10, atol=1e-12)
                other = fresh[3 - t].verify(rows, w)
                same += 1
                differ += other is None or not np.allclose(other, a, rtol=1e-6)
    assert same > 20 and differ > 10, (same, differ)  # the two Hessians give other answers
    assert any(entry.maps is not None for _, entry in cached._reduced.items())  # maps were used


@pytest.fixture(scope="module")
def closed_loop():
    model = macro()
    p3 = RecedingHorizonController(model, PAPER_K, **PAPER_RHC)
    return closed_loop_states(model, p3, 160, seed=29)


def test_warm_paths_give_the_answers_of_cold_solves(closed_loop):
    x, mode, k = closed_loop
    fast = ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=3)
    cold = ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=3)
    cold.set_warm_start(False)
    for i in range(len(x)):
        u_f, info_f = fast.act(x[i], int(mode[i]), int(k[i]))
        u_c, info_c = cold.act(x[i], int(mode[i]), int(k[i]))
        assert info_f["ok"] and info_c["ok"], (info_f["notes"], info_c["notes"])
        assert info_f["iterations"] == info_c["iterations"]
        assert np.allclose(u_f, u_c, rtol=1e-9, atol=1e-9)
        assert abs(info_f["cost"] - info_c["cost"]) <= 1e-9 * info_c["cost"]
    paths = fast.path_counts
    assert {"active_set_warm", "active_set_recent"} <= set(paths), paths
    assert set(cold.path_counts) == {"daqp"}, cold.path_counts


def test_newton_reaches_the_plain_iteration_fixed_point_in_fewer_solves(closed_loop):
    x, mode, k = closed_loop
    newton = ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=3)
    plain = ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=3)
    plain._newton = lambda *args: None  # the iteration before Newton's step: Aitken's
    longer = 0
    for i in range(len(x)):
        u_n, info_n = newton.act(x[i], int(mode[i]), int(k[i]))
        u_p, info_p = plain.act(x[i], int(mode[i]), int(k[i]))
        assert info_n["ok"] and info_p["ok"]
        assert np.allclose(u_n, u_p, rtol=0.0, atol=1e-6), (u_n, u_p)
        assert info_n["iterations"] <= info_p["iterations"]
        if info_p["iterations"] >= 3:
            longer += 1
            assert info_n["iterations"] <= 2
    assert longer >= 10, longer  # the states exercise the step


def test_band_limits_are_the_general_limits():
    rng = np.random.default_rng(3)
    for G in (np.array([[0.0, -1.0], [0.0, 1.0]]), np.array([[1.0, 2.0], [-2.0, -4.0]])):
        band = RegionClasses(G)
        general = RegionClasses(G)
        general._pair = None
        assert band._pair is not None
        H = rng.normal(size=(50, 2)) * 3.0
        for a, b in zip(band.limits(H)[:3], general.limits(H)[:3], strict=True):
            assert np.array_equal(a, b)
        assert not band.limits(H)[2].all()  # some intervals empty
        mu, sd = rng.normal(size=(50, 1)), rng.uniform(0.0, 2.0, size=(50, 1))
        sd[:5] = 0.0
        p_band = band.probability_within(mu, sd, band.limits(H))
        assert np.array_equal(p_band, general.probability_within(mu, sd, general.limits(H)))
    assert RegionClasses(np.array([[1.0, 0.0], [0.0, 1.0]]))._pair is None  # one side each


def test_earlier_sets_are_tried_while_they_pay():
    """The sets optimal before the warm one are tried when it fails (path "recent"), and no
    longer once a family's tries stop paying (RECENT_PAYOFF), except once in RECENT_PAYOFF warm
    failures; every answer is the cold solve's."""
    from controllers.tree_qp import RECENT_PAYOFF

    rng = np.random.default_rng(11)
    d, c = 6, 5
    P, C, _ = _random_qp(rng, d, c, 2)
    P.flags.writeable = False
    lower, upper = np.zeros(C.shape[0], bool), np.ones(C.shape[0], bool)
    fam = TreeQP(np.eye(d), C, lower, upper, DEFAULT_OSQP_SETTINGS, enumerate_all=False)
    cold = TreeQP(np.eye(d), C, lower, upper, DEFAULT_OSQP_SETTINGS, enumerate_all=False)
    fam.update_P(P, 1)
    cold.update_P(P)

    def instance():
        return np.concatenate(
            [rng.normal(size=d - 2) * 3.0, rng.uniform(1.0, 5.0, size=2)]
            + [rng.uniform(0.1, 2.0, size=c), np.zeros(2)]
        )

    found = {}
    while len(found) < 2:  # two instances of different optimal active sets
        w = instance()
        found.setdefault(cold.solve(w, warm=False).rows, w)
    (rows1, w1), (rows2, w2) = found.items()
    for w, rows in ((w1, rows1), (w2, rows2)):
        assert fam.solve(w).rows == rows
    sol = fam.solve(w1)  # the warm set (rows2) fails; rows1 was optimal before it
    assert sol.path == "recent" and sol.rows == rows1
    assert np.allclose(sol.z, cold.solve(w1, warm=False).z, rtol=1e-10, atol=1e-12)
    fam._recent_stats[:] = [100, 0, 0]  # tries that never paid
    paths = []
    for step in range(RECENT_PAYOFF + 1):
        w = (w2, w1)[step % 2]
        sol = fam.solve(w)
        paths.append(sol.path)
        assert np.allclose(sol.z, cold.solve(w, warm=False).z, rtol=1e-10, atol=1e-12)
    assert "recent" not in paths[:RECENT_PAYOFF] and paths[RECENT_PAYOFF] == "recent", paths


def test_families_built_counts_the_families():
    ctrl = ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=2)
    assert ctrl.families_built == 0
    for _ in range(2):  # one family: (mode 0, the region of x at k = 0)
        ctrl.act(np.array([2.0, 2.0]), 0, 0)
    assert ctrl.families_built == 1
    ctrl.act(np.array([2.0, 2.0]), 1, 0)  # another mode: another family
    assert ctrl.families_built == 2
