"""The references that ``benchmarks.speed`` times the controllers against, written from the paper
and the other libraries' public APIs only (none imports the project's controllers): problem P3
from the model and the public parameters (:class:`P3Data`, its tightening by eq.
(constraint:det_univariate) with scipy), its dense active-set floor solved by DAQP's own
``daqp.Model`` (:class:`DaqpFloor`) and a cvxpy ``Parameter`` formulation
(:class:`CvxpyParametric`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.stats import norm

from sdjls_gym import SDJLSModel

#: What DAQP reads as an infinite bound.
DAQP_INFINITY = 1e30


def individual_tightening(model: SDJLSModel, xi: float) -> np.ndarray:
    """``t[i, j] = F^{-1}_{G_j w}(xi)`` of eq. (constraint:det_univariate) (N, r): the noise
    ``E_i w`` with ``w ~ N(0, W)`` makes ``G_j E_i w`` Gaussian with standard deviation
    ``sqrt(G_j E_i W E_i' G_j')``."""
    cov = np.einsum("iab,bc,idc->iad", model.E, model.W, model.E)  # E_i W E_i'
    var = np.einsum("ja,iab,jb->ij", model.G, cov, model.G)
    return float(norm.ppf(xi)) * np.sqrt(np.maximum(var, 0.0))


class P3Data:
    """Problem P3 of a receding-horizon controller, written here from the model and the
    controller's parameters (public data only): for each (mode, x_k in C1) the QP in
    ``z = (nu, rho)``, ``min nu'H_nu nu + g'nu + alpha rho`` s.t. ``G B nu - rho <= H_{k+1} - t
    - G Atilde x``, ``|nu_i| <= nu_bound``, ``rho >= 0`` (individual chance rows, box set)."""

    def __init__(self, model: SDJLSModel, K: np.ndarray, params: dict[str, Any]) -> None:
        self.model, self.K = model, np.asarray(K, dtype=float)
        self.Psi = np.asarray(params["Psi"], dtype=float)
        self.alpha, self.nu_bound = float(params["alpha"]), float(params["nu_bound"])
        if params.get("constraint", "individual") != "individual":
            raise ValueError(
                f"constraint = {params['constraint']!r}; the speed references write individual "
                "chance constraints only"
            )
        self.tight = individual_tightening(model, float(params["xi"]))
        self._fams: dict[tuple[int, bool], dict[str, Any]] = {}

    def family(self, mode: int, inside: bool) -> dict[str, Any]:
        key = (mode, inside)
        if key not in self._fams:
            model, m, r = self.model, self.model.m, self.model.r
            Pi = np.einsum("j,jab->ab", (model.P_in if inside else model.P_out)[mode], self.Psi)
            B, R, K = model.B[mode], model.R[mode], self.K[mode]
            At = model.A[mode] + B @ K
            H_nu = R + B.T @ Pi @ B
            P = np.zeros((m + 1, m + 1))
            P[:m, :m] = H_nu + H_nu.T  # 1/2 z'Pz = nu'H_nu nu
            GB = model.G @ B
            A = np.vstack(
                [np.hstack([GB, -np.ones((r, 1))]), np.eye(m + 1)]
            )  # chance rows, then the identity (DAQP's simple bounds)
            self._fams[key] = {
                "P": P,
                "A": A,
                "H_nu": H_nu,
                "GB": GB,
                "grad": 2.0 * (R @ K + B.T @ Pi @ At),
                "GA": model.G @ At,
                "K": K,
                "tight": self.tight[mode],
                "lo": np.concatenate([np.full(r, -np.inf), np.full(m, -self.nu_bound), [0.0]]),
                "hi": np.concatenate([np.zeros(r), np.full(m, self.nu_bound), [np.inf]]),
            }
        return self._fams[key]

    def instance(self, x: np.ndarray, mode: int, k: int):
        """``(family, q, lo, hi)`` of the state: two matrix-vector products."""
        fam = self.family(mode, bool(self.model.in_region(x, k)))
        q = np.append(fam["grad"] @ x, self.alpha)
        hi = fam["hi"].copy()
        hi[: self.model.r] = self.model.H(k + 1) - fam["tight"] - fam["GA"] @ x
        return fam, q, fam["lo"], hi


class DaqpFloor:
    """The dense active-set floor: P3 of :class:`P3Data` solved by DAQP's public API alone, a
    ``daqp.Model`` per (mode, region) family set up on first use, then ``update(f, bupper,
    blower)`` and ``solve`` at every call (warm from its last working set): per call two
    matrix-vector products and one DAQP solve, no verification."""

    def __init__(self, p3: P3Data) -> None:
        self.p3 = p3
        self._models: dict[int, Any] = {}

    def solve(self, x: np.ndarray, mode: int, k: int) -> tuple[np.ndarray, bool]:
        """``(u, active)``: the input and whether a chance row or the box is active."""
        import daqp

        fam, q, lo, hi = self.p3.instance(x, mode, k)
        m, r = self.p3.model.m, self.p3.model.r
        # DAQP's order: the simple bounds on z = (nu, rho) first, then the chance rows
        bu = np.minimum(np.concatenate([hi[r:], hi[:r]]), DAQP_INFINITY)
        bl = np.maximum(np.concatenate([lo[r:], lo[:r]]), -DAQP_INFINITY)
        model = self._models.get(id(fam))
        if model is None:
            model = self._models[id(fam)] = daqp.Model()
            flag, _ = model.setup(fam["P"], q, fam["A"][:r], bu, bl)
            if flag < 0:
                raise RuntimeError(f"DAQP's setup failed on the floor's P3: exit flag {flag}")
        else:
            model.update(f=q, bupper=bu, blower=bl)
        z, _, flag, info = model.solve()
        if flag < 0:
            raise RuntimeError(f"DAQP failed on the floor's P3: exit flag {flag}")
        return fam["K"] @ x + z[:m], bool(np.any(info["lam"] != 0.0))


class CvxpyParametric:
    """P3 of :class:`P3Data` for one (mode, region) family as a cvxpy problem with
    Parameters, solved repeatedly (Clarabel)."""

    def __init__(self, p3: P3Data, mode: int, inside: bool) -> None:
        import cvxpy as cp

        fam = p3.family(mode, inside)
        m, r = p3.model.m, p3.model.r
        self.nu, self.rho = cp.Variable(m), cp.Variable(nonneg=True)
        self.g, self.rhs = cp.Parameter(m), cp.Parameter(r)
        L = np.linalg.cholesky(0.5 * (fam["H_nu"] + fam["H_nu"].T))
        objective = cp.sum_squares(L.T @ self.nu) + self.g @ self.nu + p3.alpha * self.rho
        constraints = [fam["GB"] @ self.nu - self.rho <= self.rhs, cp.abs(self.nu) <= p3.nu_bound]
        self.problem = cp.Problem(cp.Minimize(objective), constraints)
        self.p3, self.fam = p3, fam

    def solve(self, x: np.ndarray, k: int) -> np.ndarray:
        import cvxpy as cp

        fam, model = self.fam, self.p3.model
        self.g.value = fam["grad"] @ x
        self.rhs.value = model.H(k + 1) - fam["tight"] - fam["GA"] @ x
        self.problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-11, tol_gap_rel=1e-11, tol_feas=1e-11)
        return fam["K"] @ x + self.nu.value
