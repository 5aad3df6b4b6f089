"""What every receding-horizon controller shares: its parameters, their checks, its status.

:class:`RecedingHorizonBase` holds the one signature of :class:`controllers.RecedingHorizonController`,
:class:`controllers.UnconstrainedRecedingHorizonController`,
:class:`controllers.ScenarioTreeController` and
:class:`controllers.BeliefRecedingHorizonController`: the model and the gains ``K`` positional,
everything else keyword-only, with the same names, defaults and checks. A subclass with
parameters of its own declares only those, and the rest as ``**settings:
Unpack[HorizonKwargs]`` (so a type checker checks every setting of a call), with
:func:`shows_settings` (so ``help()`` and ``inspect.signature`` show every setting, its type
and its default). The checked values form one record, :class:`HorizonSettings`, which the
modules below the controllers (the QP data of P3 and of the tree, their cvxpy references) take
instead of the controller. :class:`Status` is the vocabulary of ``info["status"]``.
"""

from __future__ import annotations

import inspect
import sys
from dataclasses import dataclass
from enum import Enum
from typing import Any, TypeVar

if sys.version_info >= (3, 11):
    from typing import Required, TypedDict
else:  # pragma: no cover
    from typing_extensions import Required, TypedDict

import numpy as np

from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_bool, check_choice, check_number

from .base import MAX_STATE, Controller, check_gain, check_terminal_weights
from .chance import CONSTRAINT_KINDS, check_xi
from .design import ControllerDesign, design_from_model
from .qp import check_osqp_settings

__all__ = [
    "MAX_ALPHA",
    "MAX_NU_BOUND",
    "MAX_QP_ENTRY",
    "HorizonKwargs",
    "HorizonSettings",
    "RecedingHorizonBase",
    "Status",
    "check_slack_and_offsets",
    "shows_settings",
]

#: Largest slack penalty ``alpha`` and offset bound ``nu_bound`` accepted: up to these, answers
#: are verified optimal (tests/test_scale.py). Beyond, a unit of slack outweighs the band so much
#: that float64 cannot resolve both in one objective.
MAX_ALPHA = 1e12
MAX_NU_BOUND = 1e12

#: Largest entry of the QP's matrices (see :func:`controllers.p3.check_magnitudes`).
MAX_QP_ENTRY = 1e100

_Controller = TypeVar("_Controller", bound="RecedingHorizonBase")

#: Types accepted without conversion by the fast input check of ``act`` (bool is not among them).
_INT_TYPES = frozenset([int] + [np.dtype(c).type for c in np.typecodes["AllInteger"]])
_FLOAT64 = np.dtype(np.float64)


class Status(str, Enum):
    """``info["status"]`` of a receding-horizon decision (a ``str``: it compares equal to its
    value, e.g. ``info["status"] == "solved"``). What happened on the way is in
    ``info["notes"]`` (a str, empty when nothing is to note).

    Attributes
    ----------
    SOLVED
        The answer is the exact solution of an active set that passed the KKT test of
        :mod:`controllers.kkt` (``info["ok"]`` is True; for the scenario tree, at a converged
        fixed point). The notes list solver trouble met on the way, if any.
    UNVERIFIED
        A cvxpy answer whose active set did not verify: its offset, with the smallest slack
        that makes it feasible.
    FALLBACK_NU0
        Every solver failed: ``nu = 0`` with the smallest feasible slack.
    UNCONVERGED
        Scenario tree: the last QP was solved, but its fixed point on the branch probabilities
        did not converge within ``iterations`` solves.
    APPROXIMATE
        Scenario tree: nodes of path probability below 1e-12 were left out to reach a verified
        answer.
    """

    SOLVED = "solved"
    UNVERIFIED = "unverified"
    FALLBACK_NU0 = "fallback_nu0"
    UNCONVERGED = "unconverged"
    APPROXIMATE = "approximate"

    __str__ = str.__str__  # "solved", in f-strings too (as enum.StrEnum does)


def check_slack_and_offsets(alpha: Any, nu_bound: Any) -> tuple[float, float]:
    """``(alpha, nu_bound)``, each a number in ``(0, 1e12]`` (:data:`MAX_ALPHA`,
    :data:`MAX_NU_BOUND`), for every receding-horizon controller."""
    alpha = check_number(
        "alpha", alpha, low=0.0, low_open=True, high=MAX_ALPHA, what="penalty on the slack rho"
    )
    nu_bound = check_number(
        "nu_bound",
        nu_bound,
        low=0.0,
        low_open=True,
        high=MAX_NU_BOUND,
        what="size of the set U of offsets nu",
    )
    return alpha, nu_bound


@dataclass(frozen=True, eq=False)
class HorizonSettings:
    """The checked parameters of a receding-horizon controller (arrays read-only).

    ``chance`` says whether the chance constraints are imposed (False for
    :class:`controllers.UnconstrainedRecedingHorizonController`); ``A_tilde`` is
    ``A_i + B_i K_i`` (N, n, n), eq. (sys:stabilized_input).
    """

    # the data, the problem, the solver
    model: SDJLSModel
    K: np.ndarray
    Psi: np.ndarray
    A_tilde: np.ndarray
    chance: bool
    xi: float | None
    constraint: str
    alpha: float
    nu_bound: float
    nu_set: str
    solver: str
    osqp_settings: dict[str, Any]
    cvxpy_fallback: bool


class HorizonKwargs(TypedDict, total=False):
    """The keyword settings of :class:`RecedingHorizonBase` (``Psi`` required), as a subclass
    that adds parameters of its own takes them: ``**settings: Unpack[HorizonKwargs]``. Their
    defaults and meaning are :class:`RecedingHorizonBase`'s (``tests/test_from_model.py`` checks
    that the names and types agree)."""

    Psi: Required[np.ndarray]
    xi: float | None
    constraint: str
    alpha: float
    nu_bound: float
    solver: str
    nu_set: str
    horizon: int | None
    osqp_settings: dict[str, Any] | None
    cvxpy_fallback: bool


class RecedingHorizonBase(Controller):
    """The parameters and checks shared by the receding-horizon controllers.

    Parameters
    ----------
    model : SDJLSModel
    K : (N, m, n) array
        Pre-stabilising gains of ``u = K_theta x + nu`` (eq. eq:stabilization_input), e.g. from
        Proposition 2 or ``PAPER_K`` of the macro example.
    Psi : (N, n, n) array
        Terminal weights ``Psi_i``, symmetric positive definite (keyword, required).
    xi : float
        Chance-constraint level, strictly between 0 and 1; required where the chance constraints
        are imposed, accepted (checked) and unused by
        :class:`controllers.UnconstrainedRecedingHorizonController`.
    constraint : {"individual", "joint", "bonferroni"}
        Kind of chance constraint; see :func:`controllers.chance.tightening`.
    alpha : float
        Penalty on the slack ``rho``, in ``(0, 1e12]`` (large, e.g. 1000).
    nu_bound : float
        Size of the set ``U`` of offsets ``nu``, in ``(0, 1e12]``.
    solver : str
        ``"daqp"`` (default: the exact fast path, DAQP finding the active sets), ``"osqp"`` (the
        same with OSQP finding them), ``"cvxpy"`` (the plain cvxpy/Clarabel reference) and,
        for P3 only, ``"active_set"`` (enumeration at every call).
    nu_set : {"box", "ball"}
        ``U = {|nu_i| <= nu_bound}`` or ``U = {||nu||_2 <= nu_bound}`` (the same when ``m = 1``;
        the scenario tree takes the box only).
    horizon : int, optional
        Episode length of the environment; used only by :meth:`predict` (default: the
        environments' default, 20).
    osqp_settings : dict, optional
        Overrides of :data:`controllers.qp.DEFAULT_OSQP_SETTINGS` (e.g. ``{"max_iter": 1}``
        forces failures).
    cvxpy_fallback : bool
        Whether to try the cvxpy reference when the fast path fails, before ``nu = 0``.

    Raises
    ------
    TypeError
        An argument of the wrong type (a string or a bool for a number, a non-model).
    ValueError
        A value out of range; the message names the argument, its value and what is expected.
        Raised before any work.

    Notes
    -----
    The checked values are also kept as one record, :attr:`settings` (:class:`HorizonSettings`).
    """

    #: The solvers a subclass accepts, and its sets U.
    SOLVERS: tuple[str, ...] = ("daqp", "osqp", "cvxpy")
    NU_SETS: tuple[str, ...] = ("box", "ball")
    #: Whether the chance constraints are imposed.
    _chance_constrained = True

    def __init__(
        self,
        model: SDJLSModel,
        K: np.ndarray,
        *,
        Psi: np.ndarray,
        xi: float | None = None,
        constraint: str = "individual",
        alpha: float = 1000.0,
        nu_bound: float = 100.0,
        solver: str = "daqp",
        nu_set: str = "box",
        horizon: int | None = None,
        osqp_settings: dict[str, Any] | None = None,
        cvxpy_fallback: bool = True,
    ) -> None:
        super().__init__(model, horizon)
        model = self.model
        gains = check_gain(model, K)
        weights = check_terminal_weights(model, Psi)
        chance = self._chance_constrained
        level = check_xi(xi) if chance or xi is not None else None
        kind = check_choice("constraint", constraint, CONSTRAINT_KINDS)
        alpha, nu_bound = check_slack_and_offsets(alpha, nu_bound)
        A_tilde = model.A + model.B @ gains  # eq. (sys:stabilized_input)
        A_tilde.setflags(write=False)
        self.settings = HorizonSettings(
            model=model,
            K=gains,
            Psi=weights,
            xi=level,
            constraint=kind,
            alpha=alpha,
            nu_bound=nu_bound,
            solver=check_choice("solver", solver, self.SOLVERS),
            nu_set=check_choice("nu_set", nu_set, self.NU_SETS),
            osqp_settings=check_osqp_settings(osqp_settings),
            cvxpy_fallback=check_bool("cvxpy_fallback", cvxpy_fallback),
            chance=chance,
            A_tilde=A_tilde,
        )
        s = self.settings
        self.K, self.Psi, self.xi, self.constraint = s.K, s.Psi, s.xi, s.constraint
        self.alpha, self.nu_bound, self.solver, self.nu_set = (
            s.alpha,
            s.nu_bound,
            s.solver,
            s.nu_set,
        )
        self.osqp_settings, self.cvxpy_fallback = s.osqp_settings, s.cvxpy_fallback
        self.A_tilde = s.A_tilde
        #: active-set warm start of the fast path (see :meth:`set_warm_start`)
        self._warm_start = True
        #: how many answers each path (``info["solver"]``) gave (see :attr:`path_counts`)
        self._path_counts: dict[str, int] = {}
        #: where ``K`` and ``Psi`` came from, when :meth:`from_model` chose them
        self.design: ControllerDesign | None = None
        self._build()

    def _build(self) -> None:
        """The subclass's own set-up from :attr:`settings`, at the end of ``__init__``."""

    @classmethod
    def from_model(
        cls: type[_Controller],
        model: SDJLSModel,
        *,
        xi: float,
        K: np.ndarray | None = None,
        Psi: np.ndarray | None = None,
        psi: str = "lq_in",
        **settings: Any,
    ) -> _Controller:
        """A controller for ``model`` in one call: ``K`` by Proposition 2, a default ``Psi``.

        ``K`` and ``Psi`` are chosen by :func:`controllers.design.design_from_model` (unless
        given): the gains of Proposition 2, verified with Proposition 1, and the MJLS LQ value
        matrices as terminal weights (``psi``; Proposition 2's Lyapunov matrices where those
        fail). What was chosen is kept as :attr:`design` (a
        :class:`~controllers.design.ControllerDesign`: ``design.summary()`` says it in one
        line) and logged at INFO level on the ``"controllers"`` logger.

        Parameters
        ----------
        model : SDJLSModel
        xi : float
            Chance-constraint level, strictly between 0 and 1.
        K, Psi : arrays, optional
            Given gains or terminal weights, used as they are.
        psi : {"lq_in", "lq_out", "lq_average", "lyapunov"}
            The rule for the default ``Psi`` (see :func:`controllers.design.design_from_model`).
        **settings
            The constructor's other keyword arguments (``constraint``, ``alpha``,
            ``nu_bound``, ``solver``, ``horizon``, ... and the tree's ``steps``).

        Raises
        ------
        LMIInfeasibleError
            Proposition 2 has no solution for ``model``: pass ``K``.

        Examples
        --------
        >>> from controllers import RecedingHorizonController
        >>> from sdjls_gym.systems.macro import macro
        >>> ctrl = RecedingHorizonController.from_model(macro(), xi=0.85)
        >>> ctrl.design.Psi_source.startswith("MJLS LQ value matrices")
        True
        >>> ctrl.act([2.0, 2.0], 0, 0)[1]["ok"]
        True
        """
        design = design_from_model(model, K=K, Psi=Psi, psi=psi)
        ctrl = cls(model, design.K, Psi=design.Psi, xi=xi, **settings)
        ctrl.design = design
        return ctrl

    def _check_inputs(self, x: Any, mode: Any, k: Any) -> tuple[np.ndarray, int, int]:
        """The checks of the base class, with a shortcut for the common case: ``x`` a finite
        float64 ``(n,)`` array (used as is, not copied), ``mode`` and ``k`` Python or numpy
        ints in range. Anything else goes through the full checks (same errors)."""
        if (
            type(x) is np.ndarray
            and x.dtype is _FLOAT64
            and x.shape == self._x_shape
            and type(mode) in _INT_TYPES
            and type(k) in _INT_TYPES
            and 0 <= mode < self.model.N
            and 0 <= k <= self.max_k
            and all(-MAX_STATE <= v <= MAX_STATE for v in x.tolist())  # False for NaN
        ):
            return x, int(mode), int(k)
        return super()._check_inputs(x, mode, k)

    # ------------------------------------------------------------------ instrumentation
    @property
    def path_counts(self) -> dict[str, int]:
        """How many answers (QP solves, for the scenario tree) each path gave since the
        controller was built or :meth:`reset_path_counts` was called, keyed by the values of
        ``info["solver"]`` (``"active_set_warm"``, ``"daqp"``, ``"osqp"``, ...); a copy."""
        with self._lock:
            return dict(self._path_counts)

    def reset_path_counts(self) -> None:
        """Start :attr:`path_counts` from zero."""
        with self._lock:
            self._path_counts.clear()

    def set_warm_start(self, on: bool) -> None:
        """Switch the fast path's active-set warm start on (the default) or off. Off, every
        decision goes to the solver that finds active sets (DAQP or OSQP): the answers are the
        same exact optima, only slower (used to measure that path)."""
        on = check_bool("on", on)
        with self._lock:
            self._warm_start = on

    def _count(self, path: str) -> None:
        counts = self._path_counts
        counts[path] = counts.get(path, 0) + 1

    def _act_each(
        self, x: np.ndarray, mode: np.ndarray, k: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`act` for each state of a checked batch: ``u`` (B, m) and the arrays
        ``"nu"`` (B, m), ``"rho"``, ``"cost"``, ``"status"``, ``"notes"``, ``"ok"`` (B,)."""
        results = [self.act(xb, int(mb), int(kb)) for xb, mb, kb in zip(x, mode, k, strict=True)]
        m = self.model.m
        info: dict[str, np.ndarray] = {
            "nu": np.array([r[1]["nu"] for r in results], dtype=np.float64).reshape(-1, m),
            "rho": np.array([r[1]["rho"] for r in results], dtype=np.float64),
            "cost": np.array([r[1]["cost"] for r in results], dtype=np.float64),
            "status": np.array([r[1]["status"] for r in results] or [], dtype=object),
            "notes": np.array([r[1]["notes"] for r in results] or [], dtype=object),
            "ok": np.array([r[1]["ok"] for r in results], dtype=bool),
        }
        u = np.array([r[0] for r in results], dtype=np.float64).reshape(-1, m)
        return u, info


def shows_settings(cls: type[_Controller]) -> type[_Controller]:
    """Class decorator: ``cls.__init__``'s signature, as ``help()`` and ``inspect.signature``
    show it, is its own parameters followed by the keyword settings of
    :class:`RecedingHorizonBase` (names, types and defaults) in place of its
    ``**settings: Unpack[HorizonKwargs]``. What the call does is unchanged."""
    init = cls.__init__
    own = inspect.signature(init).parameters.values()
    base = inspect.signature(RecedingHorizonBase.__init__).parameters.values()
    parameters = [p for p in own if p.kind is not p.VAR_KEYWORD]
    parameters += [p for p in base if p.kind is p.KEYWORD_ONLY]
    init.__signature__ = inspect.signature(init).replace(parameters=parameters)  # type: ignore[attr-defined]
    return cls
