"""``python -m benchmarks.tree_picture``: the scenario tree's plan, drawn once, :mod:`benchmarks.pictures.tree`."""

from benchmarks.pictures.tree import main

__all__ = ["main"]

if __name__ == "__main__":
    main()
