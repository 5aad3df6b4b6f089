"""``python -m benchmarks.tune``: an agent's hyperparameters tuned (the RL wing), :mod:`benchmarks.rl.tune`."""

from benchmarks.rl.tune import main

__all__ = ["main"]

if __name__ == "__main__":
    main()
