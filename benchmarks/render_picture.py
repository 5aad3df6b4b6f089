"""``python -m benchmarks.render_picture``: the environment's picture and its frame rate, :mod:`benchmarks.pictures.render`."""

from benchmarks.pictures.render import main

__all__ = ["main"]

if __name__ == "__main__":
    main()
