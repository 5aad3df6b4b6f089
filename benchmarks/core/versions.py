"""The package versions a benchmark ran with, recorded in every ``summary.json``."""

from __future__ import annotations

import platform
from importlib import metadata

__all__ = ["CORE_PACKAGES", "PACKAGES", "package_versions"]

#: What the model-based benchmarks run on (the core dependencies that compute their numbers): the
#: reproduction of the paper records only these, so that its files do not depend on which
#: optional extras are installed.
CORE_PACKAGES = ("numpy", "scipy", "gymnasium", "osqp", "clarabel", "cvxpy")
#: What the RL comparison and a scored agent run on (their PyPI names).
PACKAGES = ("numpy", "gymnasium", "torch", "stable-baselines3", "osqp", "cvxpy")


def package_versions(packages: tuple[str, ...] = PACKAGES) -> dict[str, str | None]:
    """``{"python": "3.11.7", "numpy": "...", ...}`` for ``packages``; None for a package that
    is not installed.

    Read from the installed distributions' metadata, so nothing heavy (torch) is imported.
    """
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in packages:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
