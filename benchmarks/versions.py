"""The package versions a benchmark ran with, recorded in every ``summary.json``."""

from __future__ import annotations

import platform
from importlib import metadata

__all__ = ["PACKAGES", "package_versions"]

#: Distributions whose versions are recorded (their PyPI names).
PACKAGES = ("numpy", "gymnasium", "torch", "stable-baselines3", "osqp", "cvxpy")


def package_versions() -> dict[str, str | None]:
    """``{"python": "3.11.7", "numpy": "...", ...}``; None for a package that is not installed.

    Read from the installed distributions' metadata, so nothing heavy (torch) is imported.
    """
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
