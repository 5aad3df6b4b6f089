"""``python -m benchmarks.hidden``."""

from benchmarks.hidden.cli import main

main()
