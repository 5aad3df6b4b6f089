"""rliable's aggregate statistics of normalized gaps across the suite's tasks.

The score of a run on a task, as rliable expects it (higher is better), is the *improvement
over the one-step RHC* in percent, ``-gap`` (:mod:`benchmarks.suite`); the results are stated
back in gaps (lower is better) where that reads more directly (the IQM).

Reproducibility: rliable 1.2 draws the resampled runs from numpy's legacy global generator
(``np.random.choice`` in ``StratifiedBootstrap.update_indices``; its ``random_state`` is not used
there). :func:`aggregate_gaps` therefore seeds that generator with ``seed`` for the duration of
the call and restores the caller's state afterwards (:func:`seeded_legacy_generator`), so the
intervals are the same at every call and the caller's global stream is untouched. This swap of
a process-wide state is not thread-safe: do not call it from several threads at once. With one
run every resample is the table itself and the result is exact.

>>> import numpy as np
>>> a = aggregate_gaps(np.array([[-4.0, 1.0, 2.0, 30.0]]), resamples=200)
>>> a.iqm_gap, a.iqm_gap_ci95, a.probability_of_improvement
(1.5, (1.5, 1.5), 0.25)
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from benchmarks.core.stats import BOOTSTRAP_SEED
from sdjls_gym.messages import describe
from sdjls_gym.validation import check_int

__all__ = [
    "AGGREGATE_RESAMPLES",
    "PROFILE_TAUS",
    "SuiteAggregate",
    "aggregate_gaps",
    "compare_gaps",
    "iqm_interval",
    "rliable_modules",
    "seeded_legacy_generator",
]

#: Stratified-bootstrap resamples of rliable's intervals.
AGGREGATE_RESAMPLES = 2000
#: Resamples drawn when the table has one run (see :func:`aggregate_gaps`).
ONE_RUN_RESAMPLES = 10
#: Thresholds (improvement over the one-step RHC, %) of the performance profile.
PROFILE_TAUS: np.ndarray = np.linspace(-100.0, 50.0, 151)


@dataclass(frozen=True)
class SuiteAggregate:
    """rliable's aggregate statistics of a (runs, tasks) table of normalized gaps.

    Attributes
    ----------
    runs, tasks : int
        The table's shape.
    iqm_gap : float
        Interquartile mean of the normalized gaps (%, lower is better; 25% trimmed from each end
        of the runs x tasks values).
    iqm_gap_ci95 : (float, float)
        Its 95% stratified-bootstrap interval (runs resampled within each task; the point itself
        with one run).
    probability_of_improvement : float
        ``P(gap < 0)`` per task, averaged over the tasks (ties with the curve count 1/2):
        rliable's probability of improvement over the one-step RHC, whose gap is 0.
    probability_of_improvement_ci95 : (float, float)
    profile_taus : (T,) array
        Thresholds of the improvement ``-gap`` (%).
    profile, profile_ci95 : (T,) and (2, T) arrays
        Share of runs x tasks whose improvement exceeds each threshold, with its interval.
    resamples : int
        Bootstrap resamples drawn (:data:`ONE_RUN_RESAMPLES` with one run).
    """

    runs: int
    tasks: int
    iqm_gap: float
    iqm_gap_ci95: tuple[float, float]
    probability_of_improvement: float
    probability_of_improvement_ci95: tuple[float, float]
    profile_taus: np.ndarray = field(repr=False, compare=False)
    profile: np.ndarray = field(repr=False, compare=False)
    profile_ci95: np.ndarray = field(repr=False, compare=False)
    resamples: int = AGGREGATE_RESAMPLES

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        for key in ("profile_taus", "profile", "profile_ci95"):
            out[key] = np.asarray(out[key]).tolist()
        return json.loads(json.dumps(out))


# ----------------------------------------------------------------------------- aggregate
def rliable_modules() -> tuple[Any, Any]:
    """rliable's ``library`` and ``metrics`` modules, or an ImportError that says how to
    install them."""
    try:
        from rliable import library, metrics
    except ImportError as exc:
        raise ImportError(
            f'the suite\'s aggregate statistics need rliable ({exc}): pip install -e ".[suite]"'
        ) from exc
    return library, metrics


@contextlib.contextmanager
def seeded_legacy_generator(seed: int) -> Iterator[None]:
    """Seed numpy's legacy global generator for the ``with`` block, then restore the caller's
    state: the one place this project touches it, because rliable 1.2 draws from it and ignores
    its ``random_state`` (see the module docstring). Not thread-safe."""
    saved = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(saved)  # noqa: NPY002


def _checked(gaps: Any, resamples: Any, seed: Any) -> tuple[np.ndarray, int, int]:
    """``gaps`` as a finite (runs, tasks) array, and the resamples to draw: one run makes
    every stratified resample the table itself and the interval the point for any number of
    resamples, so a few (:data:`ONE_RUN_RESAMPLES`) stand for them (the Mann-Whitney test per
    task and resample of the probability of improvement costs about 1 ms)."""
    resamples = check_int("resamples", resamples, low=1)
    seed = check_int("seed", seed, low=0, high=2**32 - 1)  # the legacy generator's seeds
    gaps = np.asarray(gaps, dtype=np.float64)
    if gaps.ndim != 2 or gaps.size == 0 or not np.all(np.isfinite(gaps)):
        raise ValueError(
            f"gaps = {describe(gaps)} (shape {gaps.shape}); expected a finite (runs, tasks) "
            "array with at least one run and one task"
        )
    return gaps, (resamples if gaps.shape[0] > 1 else ONE_RUN_RESAMPLES), seed


def _iqm(rly: Any, metrics: Any, gaps: np.ndarray, resamples: int) -> tuple[float, tuple]:
    """IQM of ``gaps`` and its interval, drawn from the legacy generator as it stands."""
    iqm, ci = rly.get_interval_estimates(
        {"policy": -gaps}, lambda s: np.array([metrics.aggregate_iqm(s)]), reps=resamples
    )
    lo, hi = ci["policy"][:, 0]
    return -float(iqm["policy"][0]), (-float(hi), -float(lo))


def iqm_interval(
    gaps: np.ndarray, resamples: int = AGGREGATE_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> tuple[float, tuple[float, float]]:
    """The IQM of a (runs, tasks) table of normalized gaps and its stratified-bootstrap 95%
    interval, as :func:`aggregate_gaps` gives them, without its probability of improvement and
    profile (for many tables, e.g. one per point of a learning curve).

    >>> iqm_interval(np.array([[-4.0, 1.0, 2.0, 30.0]]))
    (1.5, (1.5, 1.5))
    """
    gaps, resamples, seed = _checked(gaps, resamples, seed)
    rly, metrics = rliable_modules()
    with seeded_legacy_generator(seed):
        return _iqm(rly, metrics, gaps, resamples)


def aggregate_gaps(
    gaps: np.ndarray, resamples: int = AGGREGATE_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> SuiteAggregate:
    """rliable's IQM, probability of improvement and performance profile of a table of
    normalized gaps ``(runs, tasks)`` in percent (lower is better; rliable is given ``-gaps``),
    with stratified-bootstrap 95% intervals drawn from ``seed`` (identical at every call).

    Raises
    ------
    ValueError
        ``gaps`` is not a finite 2-d array with at least one run and one task.
    """
    gaps, resamples, seed = _checked(gaps, resamples, seed)
    rly, metrics = rliable_modules()
    scores = -gaps  # improvement over the one-step RHC: higher is better
    runs, tasks = scores.shape
    with seeded_legacy_generator(seed):
        (iqm_gap, (lo, hi)) = _iqm(rly, metrics, gaps, resamples)
        # the one-step RHC's improvement over itself is 0 on every task (one run)
        poi, poi_ci = rly.get_interval_estimates(
            {"policy": [scores, np.zeros((1, tasks))]},
            lambda x, y: np.array([metrics.probability_of_improvement(x, y)]),
            reps=resamples,
        )
        profile, profile_ci = rly.create_performance_profile(
            {"policy": scores}, PROFILE_TAUS, reps=resamples
        )
    return SuiteAggregate(
        runs=runs,
        tasks=tasks,
        iqm_gap=iqm_gap,
        iqm_gap_ci95=(lo, hi),
        probability_of_improvement=float(poi["policy"][0]),
        probability_of_improvement_ci95=(
            float(poi_ci["policy"][0, 0]),
            float(poi_ci["policy"][1, 0]),
        ),
        profile_taus=PROFILE_TAUS.copy(),
        profile=np.asarray(profile["policy"], dtype=np.float64),
        profile_ci95=np.asarray(profile_ci["policy"], dtype=np.float64),
        resamples=resamples,
    )


def compare_gaps(
    gaps_a: np.ndarray,
    gaps_b: np.ndarray,
    resamples: int = AGGREGATE_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> dict[str, Any]:
    """Two agents' (runs, tasks) tables of normalized gaps (the same tasks, any numbers of
    runs) compared with rliable: ``"iqm_difference"``, the IQM of ``a``'s gaps minus ``b``'s
    (negative: ``a`` is cheaper), and ``"probability_of_improvement"``, the probability that a
    run of ``a`` has a lower gap than a run of ``b`` on a task (ties count a half), each with
    its stratified-bootstrap 95% interval (``"..._ci95"``; the runs of each table resampled
    independently, per task), drawn from ``seed``.

    >>> c = compare_gaps(np.array([[1.0], [2.0]]), np.array([[3.0], [4.0]]), resamples=50)
    >>> c["iqm_difference"], c["probability_of_improvement"]
    (-2.0, 1.0)
    """
    gaps_a, resamples_a, seed = _checked(gaps_a, resamples, seed)
    gaps_b, resamples_b, _ = _checked(gaps_b, resamples, seed)
    if gaps_a.shape[1] != gaps_b.shape[1]:
        raise ValueError(
            f"gaps_a has {gaps_a.shape[1]} task(s) and gaps_b {gaps_b.shape[1]}; expected the "
            "same tasks in both"
        )
    reps = max(resamples_a, resamples_b)
    rly, metrics = rliable_modules()

    def iqm_difference(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(y) - metrics.aggregate_iqm(x)])

    def improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.array([metrics.probability_of_improvement(x, y)])

    out: dict[str, Any] = {"runs_a": gaps_a.shape[0], "runs_b": gaps_b.shape[0], "resamples": reps}
    with seeded_legacy_generator(seed):  # scores (higher is better): -gaps
        for name, fn in (("iqm_difference", iqm_difference),
                         ("probability_of_improvement", improvement)):  # fmt: skip
            point, ci = rly.get_interval_estimates({"pair": [-gaps_a, -gaps_b]}, fn, reps=reps)
            out[name] = float(point["pair"][0])
            out[f"{name}_ci95"] = (float(ci["pair"][0, 0]), float(ci["pair"][1, 0]))
    return out
