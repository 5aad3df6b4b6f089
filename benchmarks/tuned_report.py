"""``python -m benchmarks.tuned_report``: a tuned configuration against the default one (the RL wing), :mod:`benchmarks.rl.tuned_report`."""

from benchmarks.rl.tuned_report import main

__all__ = ["main"]

if __name__ == "__main__":
    main()
