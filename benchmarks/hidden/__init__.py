"""The hidden wing: every task of the suite with the mode hidden
(``observe="state"``), the controllers that decide without it (certainty equivalence, the belief
RHC) and the agents of ``python -m benchmarks.compare_rl --preset hidden``, scored against the
oracle that sees it (``python -m benchmarks.hidden``, ``results/hidden``).

:mod:`.score` (every design on one task, the filter's accuracy), :mod:`.summary` (seeds summed
up, rliable across tasks, the generated conclusions), :mod:`.report` and :mod:`.figures` (the
files), :mod:`.cli` (the command line). The wing's public face: ``main`` (the command, which
``compare_rl --preset hidden`` hands its scoring to) and ``EVAL_SEEDS``.
"""

from benchmarks.hidden.cli import main
from benchmarks.hidden.score import EVAL_SEEDS

__all__ = ["EVAL_SEEDS", "main"]
