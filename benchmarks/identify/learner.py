"""The identify wing's learner: explore, identify, design on the estimate, control with the RHC.

:func:`learn` spends ``steps`` environment steps, whole episodes of the task's horizon, on the
task's raw environment under the stated exploration policy (:data:`EXPLORATION`:
:class:`controllers.ExplorationPolicy`, the task's pre-stabilizing gains ``K`` plus Gaussian
input noise and an offset), estimates the model with :func:`controllers.identify` from a
designer's template (:func:`designer_template`: the task's model with its dynamics, noise and
transition matrices replaced by placeholders), and builds the one-step receding-horizon
controller (P3) on the estimate with
:meth:`RecedingHorizonController.from_model <controllers.RecedingHorizonController.from_model>`:
``K`` by Proposition 2 and ``Psi`` the MJLS LQ value matrices of the estimate, the task's other
settings (``xi``, ``constraint``, ``alpha``, ``nu_bound``). Where Proposition 2 has no solution
for the estimate the stated fallbacks (:data:`FALLBACKS`) take over, and :class:`LearnInfo` says
which. The true model is read only to report the identification errors.

>>> controller, info = learn("SDJLS-Solar-v0", steps=500, seed=0)
>>> info.episodes, info.steps, info.fallback
(10, 500, 'none')
>>> bool(info.errors["AB"] < 0.2)
True
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from benchmarks.core.montecarlo import rollout
from controllers import (
    ExplorationPolicy,
    IdentificationInfo,
    LMIError,
    RecedingHorizonController,
    identify,
)
from sdjls_gym.model import SDJLSModel
from sdjls_gym.systems import TASKS, Task
from sdjls_gym.validation import check_choice, check_int

__all__ = [
    "EXPLORATION",
    "EXPLORATION_SEED_OFFSET",
    "FALLBACKS",
    "Exploration",
    "LearnInfo",
    "designer_template",
    "explore",
    "identification_errors",
    "learn",
    "min_episodes",
]

#: The stated exploration per task, ``u = K_theta x + mean + std * eps`` with the task's
#: pre-stabilizing gains: ``(std, mean)``, the choice of tests/test_identify.py, which recovers
#: every task's dynamics from 400 episodes. The std is a fraction of the action bound (in
#: brackets): large enough to excite ``B``, small enough that VTOL's state still visits its
#: small box; the macro task's offset 8 puts its income inside the rising band in mid-episode,
#: so that the jumps from inside the region are seen too.
EXPLORATION: dict[str, tuple[float, float]] = {
    "SDJLS-Macro-v0": (4.0, 8.0),  # 0.02 of 200
    "SDJLS-Solar-v0": (20.0, 0.0),  # 0.2 of 100
    "SDJLS-VTOL-v0": (0.3, 0.0),  # 0.01 of 30
    "SDJLS-ThreeState-v0": (0.5, 0.0),  # 0.05 of 10
    "SDJLS-Degradation-v0": (0.25, 0.0),  # 0.05 of 5
    "SDJLS-Random-v0": (2.0, 0.0),  # 0.02 of 100
}
#: The exploration's environment runs from noise seed ``EXPLORATION_SEED_OFFSET + seed``, away
#: from the evaluation's seeds (0, 1, 2); its input noise from ``default_rng([seed, 12345])``,
#: a stream independent of the environment's (one seed for both correlates the input noise
#: with the state noise and biases the estimate).
EXPLORATION_SEED_OFFSET = 10_000
#: What the controller is built from, in the order tried where Proposition 2 has no solution for
#: the estimate or its solver fails (:attr:`LearnInfo.fallback` names the one used):
#: Proposition 2's gains and the estimate's LQ value matrices (``"none"``, Proposition 2's
#: Lyapunov matrices where the LQ ones fail); the exploration's gains ``task.K`` (known to the
#: designer) with the estimate's LQ value matrices (``"task_K"``); ``task.K`` with ``Psi_i = I``
#: (``"task_K_identity"``).
FALLBACKS = ("none", "task_K", "task_K_identity")


@dataclass(frozen=True)
class Exploration:
    """The exploratory episodes of one seed, all of the task's horizon ``T``.

    Attributes
    ----------
    env_id : str
    seed : int
    x : (E, T + 1, n) array
    u : (E, T, m) array
        The inputs the environment applied (clipped to the action bound).
    mode : (E, T + 1) int array
    length : (E,) int array
        Steps each episode ran (``T`` unless it diverged).
    """

    env_id: str
    seed: int
    x: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    mode: np.ndarray = field(repr=False)
    length: np.ndarray = field(repr=False)

    @property
    def episodes(self) -> int:
        return int(self.x.shape[0])

    def trajectories(self, episodes: int) -> list[dict[str, np.ndarray]]:
        """The first ``episodes`` episodes as :func:`controllers.identify` reads them."""
        return [
            {"x": self.x[b, : L + 1], "u": self.u[b, :L], "mode": self.mode[b, : L + 1]}
            for b, L in enumerate(self.length[:episodes].tolist())
        ]


@dataclass(frozen=True)
class LearnInfo:
    """What :func:`learn` did.

    Attributes
    ----------
    env_id : str
    seed : int
    episodes, steps : int
        Exploratory episodes and the environment steps they took.
    errors : dict
        Against the true model: ``A``, ``B``, ``AB`` (``[A B]`` jointly), ``cov`` (the noise
        covariances): the largest relative Frobenius error over the modes; ``P``: the largest
        absolute error over the entries of ``P_in`` and ``P_out``.
    samples : tuple of int
        Steps of each mode in the data.
    prior_rows : int
        Transition rows never observed (their estimate is the uniform prior).
    fallback : str
        One of :data:`FALLBACKS`.
    K_source, Psi_source : str
        Where the controller's gains and terminal weights came from.
    """

    env_id: str
    seed: int
    episodes: int
    steps: int
    errors: dict[str, float]
    samples: tuple[int, ...]
    prior_rows: int
    fallback: str
    K_source: str
    Psi_source: str


def _task(task: Task | str) -> Task:
    if isinstance(task, Task):
        return task
    return TASKS[check_choice("task", task, tuple(TASKS))]


def designer_template(model: SDJLSModel) -> SDJLSModel:
    """``model`` with what the designer does not know replaced by placeholders: ``A = 0``,
    ``B = 0``, no noise, uniform ``P_in`` and ``P_out``; the region, weights and start kept."""
    N, n, m = model.N, model.n, model.m
    uniform = np.full((N, N), 1.0 / N)
    return dataclasses.replace(
        model, A=np.zeros((N, n, n)), B=np.zeros((N, n, m)), E=np.zeros((N, n, n)), W=np.eye(n),
        P_in=uniform, P_out=uniform,
    )  # fmt: skip


def min_episodes(task: Task | str) -> int:
    """The fewest whole episodes in which :func:`controllers.identify` can succeed: ``N (n + m
    + 1)`` steps (each mode its ``n + m + 1``), rounded up to episodes of the horizon."""
    t = _task(task)
    need = t.model.N * (t.model.n + t.model.m + 1)
    return max(1, -(-need // t.horizon))


def explore(task: Task | str, episodes: int, seed: int) -> Exploration:
    """``episodes`` episodes of the stated exploration (:data:`EXPLORATION`) on the task's raw
    environment, simulated together (:func:`benchmarks.core.montecarlo.rollout`); the learning
    curve takes each smaller budget of the seed as the first episodes of these."""
    t = _task(task)
    episodes = check_int("episodes", episodes, low=1)
    seed = check_int("seed", seed, low=0)
    std, mean = EXPLORATION[t.env_id]
    policy = ExplorationPolicy(
        designer_template(t.model), t.K, std, np.random.default_rng([seed, 12345]),
        input_mean=mean,
    )  # fmt: skip
    ro = rollout(t.model, policy, episodes, t.horizon, EXPLORATION_SEED_OFFSET + seed,
                 t.action_bound)  # fmt: skip
    length = np.where(ro.ended.any(axis=1), ro.ended.argmax(axis=1), t.horizon)
    return Exploration(t.env_id, seed, ro.x, ro.u, ro.mode, length.astype(np.int64))


def _relative(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Largest ``||estimate_i - truth_i||_F / ||truth_i||_F`` over the modes (the largest norm
    for a zero truth)."""
    den = np.linalg.norm(truth, axis=(1, 2))
    den = np.where(den > 0.0, den, max(float(den.max()), np.finfo(float).tiny))
    return float((np.linalg.norm(estimate - truth, axis=(1, 2)) / den).max())


def identification_errors(model: SDJLSModel, truth: SDJLSModel) -> dict[str, float]:
    """The errors of an estimate (see :attr:`LearnInfo.errors`)."""
    AB = np.concatenate([model.A, model.B], axis=2)
    AB_true = np.concatenate([truth.A, truth.B], axis=2)
    return {
        "A": _relative(model.A, truth.A),
        "B": _relative(model.B, truth.B),
        "AB": _relative(AB, AB_true),
        "cov": _relative(model.noise_cov, truth.noise_cov),
        "P": float(max(np.abs(model.P_in - truth.P_in).max(),
                       np.abs(model.P_out - truth.P_out).max())),
    }  # fmt: skip


def design(task: Task, estimate: SDJLSModel) -> tuple[RecedingHorizonController, str]:
    """The receding-horizon controller on ``estimate`` with ``task``'s settings, by the first
    of :data:`FALLBACKS` that works; returns it and the fallback's name."""
    settings = {key: value for key, value in task.rhc.items() if key != "Psi"}
    settings["horizon"] = task.horizon
    tries: tuple[dict[str, Any], ...] = (
        {},
        {"K": task.K},
        {"K": task.K, "Psi": np.array([np.eye(task.model.n)] * task.model.N)},
    )
    for name, given in zip(FALLBACKS, tries, strict=True):
        try:
            return RecedingHorizonController.from_model(estimate, **given, **settings), name
        except LMIError:  # infeasible, or the solver failed on the estimate
            continue
    raise AssertionError("unreachable: the last fallback solves no LMI")  # pragma: no cover


def learn(
    task: Task | str, steps: int, seed: int, *, exploration: Exploration | None = None
) -> tuple[RecedingHorizonController, LearnInfo]:
    """Explore for ``steps`` environment steps, identify, and build the RHC on the estimate.

    Parameters
    ----------
    task : Task or str
        A task of :data:`sdjls_gym.systems.TASKS` (or its env id).
    steps : int
        The budget: ``steps // T`` whole episodes of the task's horizon ``T``, at least
        :func:`min_episodes`.
    seed : int
        The exploration's seed (:data:`EXPLORATION_SEED_OFFSET`).
    exploration : Exploration, optional
        This seed's exploration, already simulated for at least the budget's episodes: its
        first ones are used (a learning curve re-identifies on nested data).

    Returns
    -------
    controller : RecedingHorizonController
    info : LearnInfo

    Raises
    ------
    InsufficientDataError
        The episodes leave a mode with too few steps or unexcited (:func:`controllers.identify`).
    ValueError
        A budget below :func:`min_episodes` episodes, an exploration of another task or seed,
        or too short.
    """
    t = _task(task)
    seed = check_int("seed", seed, low=0)
    low = min_episodes(t) * t.horizon
    steps = check_int("steps", steps, low=low, what=f"at least {min_episodes(t)} episode(s) "
                      f"of {t.horizon} steps")  # fmt: skip
    episodes = steps // t.horizon
    if exploration is None:
        exploration = explore(t, episodes, seed)
    elif (exploration.env_id, exploration.seed) != (t.env_id, seed) or (
        exploration.episodes < episodes
    ):
        raise ValueError(
            f"exploration holds {exploration.episodes} episode(s) of {exploration.env_id!r}, "
            f"seed {exploration.seed}; expected at least {episodes} of {t.env_id!r}, seed {seed}"
        )
    data = exploration.trajectories(episodes)
    estimate, id_info = identify(data, designer_template(t.model), return_info=True)
    controller, fallback = design(t, estimate)
    info = _info(t, seed, data, estimate, id_info, controller, fallback)
    return controller, info


def _info(t: Task, seed: int, data: list[dict[str, np.ndarray]], estimate: SDJLSModel,
          id_info: IdentificationInfo, controller: RecedingHorizonController,
          fallback: str) -> LearnInfo:  # fmt: skip
    d = controller.design
    assert d is not None  # from_model keeps its design
    return LearnInfo(
        env_id=t.env_id,
        seed=seed,
        episodes=len(data),
        steps=int(sum(len(tr["u"]) for tr in data)),
        errors=identification_errors(estimate, t.model),
        samples=tuple(int(s) for s in id_info.samples),
        prior_rows=len(id_info.prior_rows),
        fallback=fallback,
        K_source=d.K_source,
        Psi_source=d.Psi_source,
    )
