"""``python -m benchmarks.compare_rl``: the RL comparison (the RL wing), :mod:`benchmarks.rl.compare`."""

from benchmarks.rl.compare import main

__all__ = ["main"]

if __name__ == "__main__":
    main()
