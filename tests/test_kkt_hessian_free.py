"""The Hessian-free form of the KKT test gives the step-by-step test's answers.

:class:`controllers.kkt.HessianFreeMaps` solves an active set whose rows fix every variable by
two matrices built once at the Hessian 0, adding ``P z`` to the linear term per instance; the
belief controller uses it because its Hessian changes at every decision. Here it is compared
with :func:`controllers.kkt.check_active_set` without maps (the products step by step), on the
belief controller's own QPs: the active set each decision found and 30 random sets of as many rows
as variables, the same decision to accept or reject, the same ``z`` to 1e-13 of its largest
component.
The stacked quantities (``z``, the multipliers and the magnitudes of their terms, which set
the tolerances) agree to 1e-12 of the largest magnitude. The instances are the QPs of 40 decisions of the belief controller per system (the VTOL task, 2
inputs; two random systems of ``conftest.random_sdjls``, 2 and 3 inputs, 3 modes), at seeded
random states and beliefs, and the same QPs with the objective scaled by 1e-8 and 1e8 (the
minimizer does not move). With one input the controller scales its Hessian to a fixed one and
does not use this form. A third check: on a wrong active set both
forms agree on the rejection, and the accepted set's ``z`` is feasible and stationary by a dense
solve written here with numpy only.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_sdjls

from controllers import BeliefRecedingHorizonController
from controllers.kkt import (
    HessianFreeMaps,
    active_set_factor,
    check_active_set,
    reduce_hessian,
    solve_stacked,
)
from controllers.kkt_maps import hessian_free_maps
from sdjls_gym.systems import TASKS

SYSTEMS = ("SDJLS-VTOL-v0", "random-m2", "random-m3")


def controller(system: str) -> BeliefRecedingHorizonController:
    """The belief controller of a task, or of a random system with 3 modes and ``m`` inputs."""
    if system in TASKS:
        task = TASKS[system]
        return BeliefRecedingHorizonController(task.model, task.K, horizon=task.horizon,
                                               **task.rhc)  # fmt: skip
    m = int(system[-1])
    rng = np.random.default_rng(m)
    model = random_sdjls(rng, 3, 3, m, 2, 3)
    K = rng.normal(scale=0.3, size=(3, m, 3))
    return BeliefRecedingHorizonController(model, K, horizon=20, Psi=np.stack([np.eye(3)] * 3),
                                           xi=0.9, nu_bound=2.0)  # fmt: skip


def instances(system: str, count: int, seed: int):
    """``(kr, P, w, rows)`` of ``count`` decisions of the belief controller of ``system``
    (``rows``: the active set it found)."""
    ctrl = controller(system)
    seen = []
    solve = ctrl._qp.solve

    def keep(kr, P, w, **kw):
        P, w = P.copy(), w.copy()
        sol = solve(kr, P, w, **kw)
        seen.append((kr, P, w, None if sol is None else sol.rows))
        return sol

    ctrl._qp.solve = keep
    rng = np.random.default_rng(seed)
    n, N = ctrl.model.n, ctrl.model.N
    for _ in range(count):
        x = rng.normal(scale=2.0, size=n)
        belief = rng.dirichlet(np.full(N, 0.3))
        ctrl.act(x, belief, int(rng.integers(0, 20)))  # the first 20 steps
    return seen


def candidate_sets(kr, found, rng, count: int = 30):
    """The active set the controller found and ``count`` random sets of as many rows as
    variables (only those can fix every variable)."""
    c, d = kr.C.shape[0], kr.d
    sets = [found] if found is not None else []
    sets += [tuple(sorted(rng.choice(c, size=d, replace=False).tolist())) for _ in range(count)]
    return sets


@pytest.mark.parametrize("system", SYSTEMS)
@pytest.mark.parametrize("scale", [1.0, 1e-8, 1e8])
def test_the_hessian_free_form_decides_as_the_step_by_step_one(system, scale):
    compared = accepted = 0
    rng = np.random.default_rng(11)
    for kr, P, w, found in instances(system, 40, seed=3):
        P, w = P * scale, w.copy()
        w[: kr.d] *= scale  # the objective scaled: the same minimizer
        for rows in candidate_sets(kr, found, rng):
            fac = active_set_factor(kr.C, rows, kr.pivots)
            if fac is None:
                continue
            free = hessian_free_maps(fac, kr.d)
            if free is None:
                continue
            assert isinstance(free, HessianFreeMaps)
            step = check_active_set(fac, P, kr.C, w, kr.absC)
            fast = check_active_set(fac, P, kr.C, w, kr.absC, maps=free)
            compared += 1
            # the quantities and the magnitudes of their terms, the tolerances' base
            red = reduce_hessian(fac, P)
            if red is not None:
                W2 = np.concatenate([w, np.abs(w)])[:, None]
                for a, b in zip(solve_stacked(fac, red, P, W2), free.solve(P, W2), strict=True):
                    half = a.shape[0] // 2
                    scale = np.abs(a[half:]).max(initial=0.0)  # the largest magnitude
                    assert np.abs(a - b).max(initial=0.0) <= 1e-12 * scale, (rows, a, b)
            assert (step is None) == (fast is None), (rows, step, fast)
            if step is not None:
                accepted += 1
                zs, zf = np.array(step), np.array(fast)
                # round-off of the solution's scale (measured: at most 5e-16 of it)
                assert np.abs(zs - zf).max() <= 1e-13 * np.abs(zs).max(), (rows, zs, zf)
    # most decisions' optimal sets fix every variable (VTOL: 36 of 40 at scale 1), and the
    # candidates compared are hundreds
    assert accepted >= 20 and compared >= 40 * 5, (accepted, compared)


@pytest.mark.parametrize("system", SYSTEMS)
def test_an_accepted_set_is_optimal_by_a_dense_solve(system):
    """The set each decision found, where the Hessian-free form applies, is accepted by it, and
    its ``z`` is feasible with multipliers (from a dense least-squares solve of stationarity,
    numpy only) nonnegative, to 1e-8 of the data's scale."""
    for kr, P, w, rows in instances(system, 20, seed=5):
        d = kr.d
        q, h = w[:d], w[d:]
        fac = None if rows is None else active_set_factor(kr.C, rows, kr.pivots)
        free = None if fac is None else hessian_free_maps(fac, d)
        if free is None:
            continue  # this decision's optimal set leaves a direction free
        z = check_active_set(fac, P, kr.C, w, kr.absC, maps=free)
        assert z is not None, rows
        z = np.array(z)
        scale = np.abs(kr.C) @ np.abs(z) + np.abs(h)
        assert np.all(kr.C @ z - h <= 1e-9 * scale)
        CS = kr.C[list(rows)]
        grad = P @ z + q
        lam, *_ = np.linalg.lstsq(CS.T, -grad, rcond=None)
        g_scale = np.abs(P) @ np.abs(z) + np.abs(q)
        assert np.all(np.abs(CS.T @ lam + grad) <= 1e-8 * (g_scale.max() + 1.0))
        assert np.all(lam >= -1e-8 * (np.abs(lam).max() + 1.0)), lam
