"""The suite wing: a policy scored on every task, and the model-based references.

>>> from benchmarks.suite import evaluate_suite
>>> from controllers import LinearFeedbackController
>>> suite = evaluate_suite(lambda task: LinearFeedbackController(task.model, task.K),
...                        tasks=("SDJLS-Solar-v0", "SDJLS-Degradation-v0"), episodes=20)
>>> tuple(round(r.scores[0].violation, 2) for r in suite.results)
(0.04, 0.33)

The protocol across tasks lives in :mod:`benchmarks.core.suite` (its docstring states it); this
package is its public face and the study ``results/suite/``:

* ``python -m benchmarks.suite --policy package.module:factory`` prints the per-task table and
  the aggregate (``--tasks``, ``--episodes``, ``--seed``, ``--json PATH``), :mod:`.cli`;
* ``python -m benchmarks.suite`` alone computes the model-based references into
  ``results/suite/`` (:mod:`.report`, :mod:`.figures`).
"""

from benchmarks.core.suite import (
    SuiteScore,
    TaskResult,
    check_tasks,
    describe_suite,
    evaluate_suite,
)
from benchmarks.suite.cli import main, parse_args

__all__ = [
    "SuiteScore",
    "TaskResult",
    "check_tasks",
    "describe_suite",
    "evaluate_suite",
    "main",
    "parse_args",
]
