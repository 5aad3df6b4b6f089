"""The model-based controllers of the comparison on the macro task (``--preset macro``): the
curves swept over ``xi`` (:data:`MODEL_BASED_CURVES`) and the controllers without a level
(:data:`SINGLE_CONTROLLERS`), scored with the agents on the same episodes by
:mod:`benchmarks.rl.compare`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmarks.core.evaluate import REFERENCE_XIS
from benchmarks.core.reference import multistep_rhc, paper_rhc
from controllers import (
    LinearFeedbackController,
    MJLSLQRController,
    UnconstrainedRecedingHorizonController,
    tightened_set_empty,
)
from sdjls_gym.systems.macro import HORIZON, PAPER_K, PAPER_RHC

__all__ = ["MODEL_BASED_CURVES", "SINGLE_CONTROLLERS", "ModelBasedCurve", "empty_band_share"]

XI_SWEEP = REFERENCE_XIS


@dataclass(frozen=True)
class ModelBasedCurve:
    """A model-based controller over a sweep of its level ``xi``: one point per level, named
    ``"<family> xi=<xi>"``. The first entry of :data:`MODEL_BASED_CURVES` is the reference that
    every controller's paired gap is measured against (:data:`benchmarks.evaluate.REFERENCE_XIS`).
    """

    family: str
    build: Callable[[Any, float], Any]  # (model, xi) -> controller
    xis: tuple[float, ...] = XI_SWEEP
    constraint: str | None = None  # for the share of steps with an empty tightened band
    color: str = "k"
    #: the levels scored with ``--quick`` (default: all of ``xis``), for a slow controller
    quick_xis: tuple[float, ...] | None = None
    #: whether every other controller's cost is also compared with this curve, paired over the
    #: episodes at the controller's own violation frequency (:func:`benchmarks.rl.report.against_curve`)
    compared_against: bool = False

    def levels(self, quick: bool) -> tuple[float, ...]:
        """The levels ``xi`` scored (:attr:`quick_xis` with ``--quick``)."""
        return self.quick_xis if quick and self.quick_xis is not None else self.xis


#: The model-based curves of the comparison; add a row to add a curve.
MODEL_BASED_CURVES: tuple[ModelBasedCurve, ...] = (
    ModelBasedCurve(
        "RHC individual",
        lambda m, xi: paper_rhc(m, xi, "individual"),
        constraint="individual",
        color="k",
    ),  # fmt: skip
    ModelBasedCurve(
        "RHC joint", lambda m, xi: paper_rhc(m, xi, "joint"), constraint="joint", color="0.45"
    ),  # fmt: skip
    # the multi-step controller: a fully branched scenario tree of 3 stages; the
    # root's chance constraint is P3's, so the tightened band is the one-step curve's
    ModelBasedCurve(
        "RHC 3-step",
        lambda m, xi: multistep_rhc(m, xi, 3, "individual"),
        constraint="individual",
        color="C4",
        quick_xis=(0.5, 0.85, 0.95),
        compared_against=True,
    ),  # fmt: skip
)

#: The model-based controllers without a level: ``(name, family, build(model))``.
SINGLE_CONTROLLERS: tuple[tuple[str, str, Callable[[Any], Any]], ...] = (
    (
        "RHC unconstrained",
        "RHC unconstrained",
        lambda m: UnconstrainedRecedingHorizonController(
            m,
            PAPER_K,
            Psi=PAPER_RHC["Psi"],
            alpha=PAPER_RHC["alpha"],
            nu_bound=PAPER_RHC["nu_bound"],
            horizon=HORIZON,
        ),  # fmt: skip
    ),
    (
        "Linear feedback (nu = 0)",
        "Linear feedback",
        lambda m: LinearFeedbackController(m, PAPER_K, horizon=HORIZON),
    ),  # fmt: skip
    ("MJLS LQR", "MJLS LQR", lambda m: MJLSLQRController(m, "average", horizon=HORIZON)),
)


def empty_band_share(model: Any, xi: float, constraint: str) -> float:
    """Share of the (mode, next time) pairs of an episode at which the tightened band
    ``{y : G y <= H_{k+1} - t}`` is empty (:func:`controllers.tightened_set_empty`): there the
    QP is feasible only through its slack, whatever the state."""
    return float(
        np.mean([tightened_set_empty(model, xi, k, constraint) for k in range(1, HORIZON + 1)])
    )
