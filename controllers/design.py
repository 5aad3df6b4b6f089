"""A receding-horizon controller's data from a model alone: gains ``K`` and terminal weights ``Psi``.

For users who bring their own system: :func:`design_from_model` synthesizes the pre-stabilizing
gains by Proposition 2 (:func:`controllers.synthesize_gains`) and takes as terminal weights the
value matrices ``X_i`` of the MJLS LQ problem (the coupled Riccati equations,
:class:`controllers.MJLSLQRController`), the recipe of the suite's tasks (``sdjls_gym/systems``).
``RecedingHorizonController.from_model`` and ``ScenarioTreeController.from_model`` call it and
keep its :class:`ControllerDesign` as their ``design`` attribute.

Why the LQ value matrices: ``Psi_i`` weighs the expected next state in P3's objective, in place
of the cost still to come; ``X_i`` is that cost-to-go of the unconstrained LQ problem,
``x' X_i x``. When they are not available (the Riccati iteration fails, or an ``X_i`` is only
semidefinite because ``Q`` is), the Lyapunov matrices ``P_i = X_i^{-1}`` of Proposition 2, which
certify the pre-stabilized loop and are positive definite by construction, take their place, and
the design says so.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from sdjls_gym.errors import LMIInfeasibleError, RiccatiConvergenceError
from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_choice

from .base import check_gain, check_model, check_terminal_weights, frozen
from .baselines import MJLSLQRController
from .lmi import GainSynthesisResult, synthesize_gains

__all__ = ["PSI_CHOICES", "ControllerDesign", "design_from_model"]

#: The rules for a default ``Psi``: the LQ value matrices with ``P_in``, with ``P_out``, with their
#: average, or Proposition 2's Lyapunov matrices.
PSI_CHOICES = ("lq_in", "lq_out", "lq_average", "lyapunov")

LOG = logging.getLogger("controllers")


@dataclass(frozen=True, eq=False)
class ControllerDesign:
    """What :func:`design_from_model` chose, and why.

    Attributes
    ----------
    K : (N, m, n) ndarray
        The pre-stabilizing gains.
    Psi : (N, n, n) ndarray
        The terminal weights.
    K_source, Psi_source : str
        Where each came from, in words (``"given"`` when the caller passed it).
    gains : GainSynthesisResult or None
        Proposition 2's solution (None when ``K`` was given).
    """

    K: np.ndarray
    Psi: np.ndarray
    K_source: str
    Psi_source: str
    gains: GainSynthesisResult | None

    def summary(self) -> str:
        """One line: where ``K`` and ``Psi`` came from."""
        return f"K: {self.K_source}; Psi: {self.Psi_source}"


def _smallest_eigenvalue_ratio(mats: np.ndarray) -> float:
    """Smallest eigenvalue over the largest, over all matrices (N, n, n)."""
    eig = np.linalg.eigvalsh(mats)
    return float(eig.min() / max(float(np.abs(eig).max()), np.finfo(float).tiny))


def _lq_weights(model: SDJLSModel, rule: str) -> tuple[np.ndarray | None, str]:
    """The LQ value matrices ``X_i`` for ``rule`` (``"lq_in"``, ...), or None and why not."""
    transition = rule.removeprefix("lq_")
    try:
        X = np.array(MJLSLQRController(model, transition).X)
    except RiccatiConvergenceError as exc:
        return None, f"the MJLS LQ iteration with {transition!r} failed ({exc})"
    if _smallest_eigenvalue_ratio(X) <= 1e-9:  # Q semidefinite: X_i may be too
        return None, f"an LQ value matrix with {transition!r} is not positive definite"
    return X, (
        f"MJLS LQ value matrices X_i (coupled Riccati equations with the transition matrix "
        f"{transition!r})"
    )


def design_from_model(
    model: SDJLSModel,
    *,
    K: Any = None,
    Psi: Any = None,
    psi: str = "lq_in",
    lmi_solver: str | None = None,
) -> ControllerDesign:
    """Gains and terminal weights for a receding-horizon controller of ``model``.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array, optional
        Pre-stabilizing gains; default: Proposition 2 (:func:`controllers.synthesize_gains`,
        eqs. lmi:stabiization1, lmi:stabiization2), verified with Proposition 1.
    Psi : (N, n, n) array, optional
        Terminal weights; default: by the rule ``psi``.
    psi : {"lq_in", "lq_out", "lq_average", "lyapunov"}
        The default ``Psi``: the MJLS LQ value matrices with ``P_in`` (default: the suite's
        recipe), ``P_out`` or their average; or Proposition 2's Lyapunov matrices
        ``P_i = X_i^{-1}``. An LQ rule that fails (the Riccati iteration does not converge, or
        an ``X_i`` is not positive definite) falls back to the Lyapunov matrices, and
        :attr:`ControllerDesign.Psi_source` says why.
    lmi_solver : str, optional
        The cvxpy solver of Proposition 2 (default: Clarabel).

    Returns
    -------
    ControllerDesign

    Raises
    ------
    LMIInfeasibleError
        Proposition 2 has no solution for ``model`` (no mode-dependent gain of its form is
        certified); the message says to pass ``K``.
    TypeError, ValueError
        A bad argument, named.
    """
    model = check_model(model)
    psi = check_choice("psi", psi, PSI_CHOICES)
    gains: GainSynthesisResult | None = None
    if K is None:
        try:
            gains = synthesize_gains(model, solver=lmi_solver)
        except LMIInfeasibleError as exc:
            raise LMIInfeasibleError(
                f"{exc}. from_model synthesizes K by Proposition 2, which has no solution for "
                "this model; pass your own pre-stabilizing gains as K=(N, m, n) array, or "
                "check that the model is mean-square stabilizable"
            ) from exc
        gains_K = gains.K
        K_source = (
            f"Proposition 2 (synthesize_gains, solver {gains.solver}, Proposition-1 margin "
            f"{gains.margin:.3g})"
        )
    else:
        gains_K = check_gain(model, K)
        K_source = "given"
    if Psi is not None:
        weights = check_terminal_weights(model, Psi)
        Psi_source = "given"
    else:
        X: np.ndarray | None = None
        why = ""
        if psi != "lyapunov":
            X, why = _lq_weights(model, psi)
        if X is not None:
            weights, Psi_source = check_terminal_weights(model, X), why
        else:
            if gains is None:  # K was given: Proposition 2 only for its Lyapunov matrices
                gains = synthesize_gains(model, solver=lmi_solver)
            weights = check_terminal_weights(model, gains.P)
            Psi_source = "Proposition 2's Lyapunov matrices P_i = X_i^{-1}"
            if psi != "lyapunov":
                Psi_source += f" ({why})"
    design = ControllerDesign(frozen(gains_K), frozen(weights), K_source, Psi_source, gains)
    LOG.info("controller designed from the model: %s", design.summary())
    return design
