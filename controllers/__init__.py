"""Controllers for SDJLS models: LMI pre-stabilization, chance constraints, receding horizon,
and the model identified from exploratory trajectories.

Controllers read an :class:`sdjls_gym.SDJLSModel`; they never simulate. Their exceptions live
in :mod:`sdjls_gym.errors` with the library's others; the LMI ones, ``InsufficientDataError`` and
those of a hidden mode (``ModeNotObservedError``, ``ImpossibleObservationError``) are exported
here too.
"""

from controllers.base import Controller
from controllers.baselines import LinearFeedbackController, MJLSLQRController
from controllers.belief import BeliefRecedingHorizonController
from controllers.chance import row_satisfaction_probability, tightened_set_empty, tightening
from controllers.env_policy import ControllerPolicy, policy_for
from controllers.exploration import ExplorationPolicy
from controllers.hidden_policy import HiddenModePolicy
from controllers.horizon import Status
from controllers.identify import IdentificationInfo, identify
from controllers.lmi import (
    GainSynthesisResult,
    check_proposition2,
    synthesize_gains,
)
from controllers.mean_square import (
    MeanSquareCertificate,
    second_moment_spectral_radius,
    verify_mean_square_bound,
)
from controllers.mode_filter import ModeFilter
from controllers.rhc import RecedingHorizonController, UnconstrainedRecedingHorizonController
from controllers.scenario_tree import ScenarioTreeController
from sdjls_gym.errors import (
    ImpossibleObservationError,
    InsufficientDataError,
    LMIError,
    LMIInfeasibleError,
    LMISolverError,
    ModeNotObservedError,
)

__all__: list[str] = []
__all__ += [
    "GainSynthesisResult",
    "ImpossibleObservationError",
    "LMIError",
    "LMIInfeasibleError",
    "LMISolverError",
    "MeanSquareCertificate",
    "ModeNotObservedError",
    "check_proposition2",
    "second_moment_spectral_radius",
    "synthesize_gains",
    "verify_mean_square_bound",
]
__all__ += [
    "BeliefRecedingHorizonController",
    "Controller",
    "ControllerPolicy",
    "ExplorationPolicy",
    "HiddenModePolicy",
    "LinearFeedbackController",
    "MJLSLQRController",
    "ModeFilter",
    "RecedingHorizonController",
    "ScenarioTreeController",
    "Status",
    "UnconstrainedRecedingHorizonController",
    "policy_for",
    "row_satisfaction_probability",
    "tightened_set_empty",
    "tightening",
]
__all__ += ["IdentificationInfo", "InsufficientDataError", "identify"]
