"""The benchmarks' one log: the ``logging`` module, a ``benchmarks`` logger with timestamps.

The scripts report progress with :func:`log` (``[HH:MM:SS] message`` on standard error). Its
handler writes through ``tqdm.write`` so that a line never breaks a progress bar, and is set up
once, on first use, only where no handler of the ``benchmarks`` logger exists: a user's own
``logging`` configuration takes over.
"""

from __future__ import annotations

import logging
import sys

__all__ = ["LOGGER", "log"]

LOGGER = logging.getLogger("benchmarks")


class _TqdmHandler(logging.Handler):
    """Lines through ``tqdm.write``: printed above a running progress bar, not into it."""

    def emit(self, record: logging.LogRecord) -> None:
        from tqdm import tqdm

        try:
            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging's contract: report, never raise
            self.handleError(record)


def _configure() -> None:
    if LOGGER.handlers:
        return
    handler = _TqdmHandler()
    handler.setFormatter(logging.Formatter("[%(asctime)s] %(message)s", datefmt="%H:%M:%S"))
    LOGGER.addHandler(handler)
    LOGGER.setLevel(logging.INFO)
    LOGGER.propagate = False


def log(message: str) -> None:
    """Log ``message`` at INFO on the ``benchmarks`` logger (``[HH:MM:SS] message``)."""
    _configure()
    LOGGER.info(message)
