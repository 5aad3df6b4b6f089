"""``python -m benchmarks.identify``."""

from benchmarks.identify.cli import main

main()
