"""Every exception of the library, on builtin bases.

Each class subclasses the builtin exception a caller would catch anyway (``ValueError`` for bad
data, ``TypeError`` for a wrong type, ``RuntimeError`` for a failure at run time), so
``except ValueError`` keeps working; catch the class itself to tell the library's errors apart.
Two classes are both a ``TypeError`` and a ``ValueError``: a mistake that is one by the
project's rules (a float is not an int; a string is not a number) in a place that has always
reported bad input as the other.

==============================  ====================================  ===================================
class                           bases                                 raised when
==============================  ====================================  ===================================
``InvalidModelError``           ``ValueError``                        a model or model file is malformed
``InvalidModelTypeError``       ``InvalidModelError``, ``TypeError``  a model field has the wrong type
``InvalidRunError``             ``ValueError``                        a kept RL run's files are bad
``NotAnIntError``               ``TypeError``, ``ValueError``         a float where an int belongs
``NotANumberError``             ``TypeError``, ``ValueError``         an action entry is not a number
``ResetNeededError``            ``gymnasium.error.ResetNeeded``,      ``step()`` before ``reset()`` or
                                ``RuntimeError``                      after the episode ended
``LMIError``                    ``RuntimeError``                      an LMI problem gave no answer
``LMIInfeasibleError``          ``LMIError``, ``ValueError``          the LMIs are infeasible
``LMISolverError``              ``LMIError``                          the LMI solver failed
``RiccatiConvergenceError``     ``RuntimeError``                      the Riccati iteration failed
``ModeNotObservedError``        ``ValueError``                        the mode is needed but not observed
``ImpossibleObservationError``  ``ValueError``                        no mode explains an observed state
``InsufficientDataError``       ``ValueError``                        trajectories do not determine a
                                                                      model (``controllers.identify``)
==============================  ====================================  ============================
The package namespaces export the ones users catch most: ``sdjls_gym.InvalidModelError``,
``sdjls_gym.InvalidModelTypeError``, ``controllers.LMIError`` and its subclasses,
``controllers.ModeNotObservedError``, ``controllers.ImpossibleObservationError`` and
``controllers.InsufficientDataError``.
"""

from __future__ import annotations

from gymnasium.error import ResetNeeded

__all__ = [
    "InvalidModelError",
    "InvalidModelTypeError",
    "InvalidRunError",
    "NotAnIntError",
    "NotANumberError",
    "ResetNeededError",
    "LMIError",
    "LMIInfeasibleError",
    "LMISolverError",
    "RiccatiConvergenceError",
    "ModeNotObservedError",
    "ImpossibleObservationError",
    "InsufficientDataError",
]


class InvalidModelError(ValueError):
    """A model (or a model file) is malformed. Subclass of :class:`ValueError`.

    Raised by :class:`~sdjls_gym.SDJLSModel` (and ``from_dict``) for a field of the wrong shape
    or value (a row of ``P_in`` that does not sum to 1, an ``R`` that is not positive
    definite, ...), and by :func:`~sdjls_gym.load_model` for a file that does not parse, nests
    too deep, repeats a key or holds a bad field. The message names the field (and the file).
    """


class InvalidModelTypeError(InvalidModelError, TypeError):
    """A model field has the wrong type (a string, a bool or None where numbers belong, names
    given as a generator).

    Both an :class:`InvalidModelError` (so a :class:`ValueError`) and a :class:`TypeError`, so
    ``except InvalidModelError`` catches every model error.
    """


class InvalidRunError(ValueError):
    """A kept run of the RL comparison (``benchmarks.rl.runs``) cannot be used. Subclass of
    :class:`ValueError`.

    Raised by ``benchmarks.rl.runs.read_run`` and ``load_agent`` (so by ``python -m
    benchmarks.evaluate --run`` and ``python -m benchmarks.rl.compare --score-only``) for a
    record that is not a run record (not a JSON object, nested too deep, a field missing or of
    the wrong type), that was edited (its fingerprint, configuration, file name or task digest
    disagree), or whose policy file is truncated or is another network's. The message names the
    file and what is wrong.
    """


class NotAnIntError(TypeError, ValueError):
    """A float (or another real number that is not an int) given where an int is expected
    (``horizon=2.0``, ``steps=2.5``).

    Both a :class:`TypeError` (the project's rule: a float is not an int) and a
    :class:`ValueError` (``steps = 2.5`` is also a bad value for a count). Raised by
    :func:`sdjls_gym.validation.check_int` and every check built on it.
    """


class NotANumberError(TypeError, ValueError):
    """An entry that is not a real number (a string, a bool, None) where numbers are expected,
    in a call that has always reported bad input as :class:`ValueError`: the environments'
    ``step`` (an action ``["1"]`` or ``[True]`` is not read as 1.0).

    Both a :class:`TypeError` (the project's rule) and a :class:`ValueError`. Raised by
    :func:`sdjls_gym.validation.check_numbers`.
    """


class ResetNeededError(ResetNeeded, RuntimeError):
    """``SDJLSEnv.step()`` before ``reset()``, or after the episode ended (Gymnasium's
    convention; the vector environment resets by itself instead).

    Both a :class:`gymnasium.error.ResetNeeded` and a :class:`RuntimeError`.
    """


class LMIError(RuntimeError):
    """Base class of the errors of the LMI functions (``controllers.synthesize_gains``,
    ``controllers.verify_mean_square_bound``): an LMI problem gave no usable answer."""


class LMIInfeasibleError(LMIError, ValueError):
    """The solver reports the LMIs infeasible, or the gains are clearly not mean-square
    stabilizing before any solver runs (also a :class:`ValueError`: the data are bad)."""


class LMISolverError(LMIError):
    """The LMI solver failed, was inaccurate, or its answer did not pass the float64 check of
    Proposition 1; the message names the solver and its status."""


class RiccatiConvergenceError(RuntimeError):
    """The coupled Riccati iteration of ``controllers.MJLSLQRController`` diverged or did not
    converge within ``max_iter`` iterations (the Markov jump linear system is then not
    mean-square stabilizable with that transition matrix)."""


class ModeNotObservedError(ValueError):
    """Something that needs the mode ``theta_k`` was given an environment or an observation
    that does not show it (``observe="state"``): a controller's ``predict`` given the
    state-only observation ``[x, k / horizon]``, or ``ResidualAction`` with gains that differ
    by mode on such an environment. The message says what would work instead (the belief of
    ``controllers.ModeFilter``, one gain for every mode)."""


class ImpossibleObservationError(ValueError):
    """``controllers.ModeFilter`` was given a state ``x_{k+1}`` that no mode of positive
    belief can produce from ``(x_k, u_k)``: the belief would be all zero. Either a residual
    lies outside the range of a singular noise covariance in every such mode, or every
    log-likelihood is below float64's range. Usually the input is not the one applied
    (``info["u"]``), the states are not the environment's, or the model differs."""


class InsufficientDataError(ValueError):
    """The trajectories given to ``controllers.identify`` do not determine the model: a mode is
    never the mode of a step, its steps are fewer than ``n + m + 1``, or its regressors
    ``[x_k, u_k]`` have rank below ``n + m`` (the inputs were not excited independently of the
    state). The message names the mode, what is missing and the remedy (more exploration, input
    noise). A :class:`ValueError`: the data are bad."""
