"""The speed wing: the environment and the controllers timed against references in the same run.

``python -m benchmarks.speed [--out results/speed] [--quick]`` (:mod:`.measure`; the references,
written against the other libraries' public APIs: :mod:`.references`; ``SPEED.md``:
:mod:`.report`).
"""

from benchmarks.speed.measure import main

__all__ = ["main"]
