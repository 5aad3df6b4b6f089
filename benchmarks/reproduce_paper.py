"""``python -m benchmarks.reproduce_paper``: section 6 of the paper reproduced (the paper wing), :mod:`benchmarks.paper.reproduce`."""

from benchmarks.paper.reproduce import main

__all__ = ["main"]

if __name__ == "__main__":
    main()
