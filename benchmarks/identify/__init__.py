"""The identify wing: learn the model, then control, at the agents' budgets.

``python -m benchmarks.identify`` (:mod:`.cli`) explores each task of the suite with a stated
policy, identifies the model (:func:`controllers.identify`), designs the receding-horizon
controller on the estimate (:mod:`.learner`), scores it with the core's protocol at a grid of
environment-step budgets that covers the agents' learning curves (:mod:`.steps`, :mod:`.run`),
and writes ``results/identify/`` beside the agents' curves read from ``results/rl_suite``
(:mod:`.agents`, :mod:`.summary`, :mod:`.report`, :mod:`.figures`).

The wing's public face: the learner (``learn``, ``explore``, ``LearnInfo``, ``EXPLORATION``),
the grid and the within-5% rule (``step_grid``, ``steps_within``, ``across_seeds``), the
evaluation seeds (``EVAL_SEEDS``) and the command (``main``).
"""

from benchmarks.identify.cli import main
from benchmarks.identify.learner import EXPLORATION, LearnInfo, explore, learn
from benchmarks.identify.run import EVAL_SEEDS
from benchmarks.identify.steps import across_seeds, step_grid, steps_within

__all__ = [
    "EVAL_SEEDS",
    "EXPLORATION",
    "LearnInfo",
    "across_seeds",
    "explore",
    "learn",
    "main",
    "step_grid",
    "steps_within",
]
