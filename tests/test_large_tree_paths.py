"""The paths of issue 29 for large trees against the plain computations they stand for.

What is checked, and against what:

* DAQP on a whitened QP (:attr:`controllers.dual_qp.DaqpData.white`) against DAQP on the QP as
  it is, on random QPs with slacks (variables without curvature), simple bounds or none, a
  subset of the rows and a warm start (seeded: 24 problems of 40 variables): the same solution
  and multipliers to 1e-7 of their scale (both are DAQP's answers, to its tolerances); a
  singular curved block is not whitened;
* Clarabel's hint (:mod:`controllers.qp_ipm`) on the 111-node tree against the same tree
  without it (DAQP from the warm set): the same verified decisions to 1e-9 on 16 closed-loop
  states, the hint's path met; a hint that fails, or points at a wrong set, still gives the
  verified optimum;
* the records of the warm tries, shared by the families of one controller.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from benchmarks.speed.measure import large_tree_model
from controllers import ScenarioTreeController, qp_daqp
from controllers.dual_qp import WHITEN_MIN_VARIABLES, daqp_data, run_daqp
from sdjls_gym import SDJLSVectorEnv


def _random_family(rng: np.random.Generator, d: int, slacks: int, rows: int, simple: bool):
    """``(P, A, lo, hi)``: a Hessian zero on the last ``slacks`` variables, ``rows`` general
    rows (each slack in a few of them with coefficient -1), then with ``simple`` the identity
    rows (a box on the curved variables, ``>= 0`` on the slacks)."""
    L = rng.normal(size=(d, d)) * rng.uniform(0.1, 10.0, size=d)
    P = L @ L.T
    P[d - slacks :, :] = 0.0
    P[:, d - slacks :] = 0.0
    G = rng.normal(size=(rows, d)) * (rng.random((rows, d)) < 0.3)
    G[:, d - slacks :] = 0.0
    G[np.arange(rows), d - slacks + np.arange(rows) % slacks] = -1.0
    hi_g = rng.uniform(0.1, 2.0, size=rows)
    if not simple:
        return P, G, np.full(rows, -np.inf), hi_g
    A = np.vstack([G, np.eye(d)])
    box = rng.uniform(0.5, 3.0, size=d - slacks)
    lo = np.concatenate([np.full(rows, -np.inf), -box, np.zeros(slacks)])
    hi = np.concatenate([hi_g, box, np.full(slacks, np.inf)])
    return P, A, lo, hi


@pytest.mark.parametrize("simple", [True, False])
def test_whitened_daqp_gives_the_plain_answer(simple):
    rng = np.random.default_rng(29)
    d, slacks, rows = 40, 12, 160
    assert d >= WHITEN_MIN_VARIABLES
    for trial in range(12):
        P, A, lo, hi = _random_family(rng, d, slacks, rows, simple)
        data = daqp_data(P, A, simple)
        assert data.white is not None and data.white.nz == slacks
        plain = replace(data, white=None)
        q = rng.normal(size=d) * 10.0 ** rng.uniform(-1, 2)
        q[d - slacks :] = rng.uniform(1.0, 50.0, size=slacks)  # the slacks' linear cost
        subset = np.sort(rng.choice(rows, size=rows // 2, replace=False)) if trial % 2 else None
        z0, y0, s0 = run_daqp(plain, q, lo, hi, None, 0.0, subset)
        assert z0 is not None and y0 is not None, s0
        # a warm start: the rows DAQP ended on, less one, so that it has work to do
        warm = [(int(a), bool(y0[a] < 0)) for a in np.flatnonzero(y0)][1:]
        for start in (None, warm):
            z1, y1, s1 = run_daqp(data, q, lo, hi, start, 0.0, subset)
            assert z1 is not None and y1 is not None, s1
            scale_z = max(1.0, float(np.max(np.abs(z0))))
            scale_y = max(1.0, float(np.max(np.abs(y0))))
            np.testing.assert_allclose(z1, z0, rtol=0, atol=1e-7 * scale_z)
            np.testing.assert_allclose(y1, y0, rtol=0, atol=1e-7 * scale_y)


def test_a_singular_curved_block_is_not_whitened():
    rng = np.random.default_rng(3)
    P, A, _, _ = _random_family(rng, 40, 8, 100, True)
    u = rng.normal(size=(40, 1))
    u[32:] = 0.0
    P = u @ u.T  # rank one on the curved variables
    assert daqp_data(P, A, True).white is None
    assert daqp_data(np.eye(8), np.eye(8), True).white is None  # too small to pay


def _tree():
    model = large_tree_model()
    n, N = model.n, model.N
    return ScenarioTreeController(
        model, np.zeros((N, 1, n)), Psi=np.tile(np.eye(n), (N, 1, 1)), xi=0.9, steps=3
    )


def _closed_loop(count: int, skip: int):
    """``count`` closed-loop states of the 111-node tree after ``skip`` (seeded)."""
    model = large_tree_model()
    ctrl, env = _tree(), SDJLSVectorEnv(num_envs=1, model=model)
    _, info = env.reset(seed=3)
    states = []
    for step in range(skip + count):
        state = (info["state"][0].copy(), int(info["mode"][0]), int(info["k"][0]))
        if step >= skip:
            states.append(state)
        u, _ = ctrl.act(*state)
        _, _, term, trunc, info = env.step(u[None])
        if term[0] or trunc[0]:
            _, info = env.reset()
    return states


@pytest.fixture(scope="module")
def tree_states():
    return _closed_loop(16, 8)


def _decide(states, hint=None):
    ctrl, out = _tree(), []
    with pytest.MonkeyPatch.context() as mp:
        if hint is not None:
            mp.setattr(qp_daqp, "interior_point_rows", hint)
        for state in states:
            out.append(ctrl.act(*state)[1])
    return ctrl, out


@pytest.fixture(scope="module")
def hinted(tree_states):
    return _decide(tree_states)


def _same(a: dict, b: dict) -> None:
    assert a["ok"] and b["ok"], (a["status"], b["status"])
    np.testing.assert_allclose(a["nu"], b["nu"], rtol=1e-9, atol=1e-12)
    assert a["rho"] == pytest.approx(b["rho"], rel=1e-9, abs=1e-12)
    assert a["cost"] == pytest.approx(b["cost"], rel=1e-9)


def test_clarabel_hint_gives_the_decisions_of_daqp(tree_states, hinted, monkeypatch):
    ctrl, got = hinted
    assert ctrl.path_counts.get("clarabel", 0) >= 1, ctrl.path_counts
    monkeypatch.setattr(qp_daqp, "IPM_MIN_VARIABLES", 10**9)  # no hint: DAQP from the warm set
    plain_ctrl, plain = _decide(tree_states)
    assert "clarabel" not in plain_ctrl.path_counts
    for a, b in zip(got, plain, strict=True):
        _same(a, b)


@pytest.mark.parametrize("kind", ["none", "wrong", "raises"])
def test_a_failed_or_wrong_hint_still_gives_the_optimum(tree_states, hinted, kind, monkeypatch):
    calls = []

    def hint(P, C, q, h):
        calls.append(1)
        if kind == "none":
            return None
        return tuple(range(P.shape[0] // 2))  # the first chance rows: not the optimum's

    if kind == "raises":  # Clarabel itself fails: interior_point_rows gives None

        class Broken:
            def __init__(self, *args, **kwargs):
                calls.append(1)
                raise RuntimeError("broken solver")

        import clarabel

        monkeypatch.setattr(clarabel, "DefaultSolver", Broken)
        ctrl, got = _decide(tree_states)
    else:
        ctrl, got = _decide(tree_states, hint=hint)
    assert calls, "the hint was never asked for"
    assert "clarabel" not in ctrl.path_counts
    for a, b in zip(got, hinted[1], strict=True):
        _same(a, b)


def test_families_of_one_controller_share_their_records(hinted):
    ctrl, _ = hinted
    engines = [fam.engine for fam in ctrl._families.values()]
    assert len(engines) >= 2
    assert all(e._recent_stats is engines[0]._recent_stats for e in engines)
    assert all(e._repair_stats is engines[0]._repair_stats for e in engines)
    assert engines[0]._recent_stats is not engines[0]._repair_stats
