"""The pieces every cost-against-violation figure of the benchmarks shares: a point with its two
intervals, and the axes (the ``1 - xi`` line, scales, labels, grid, legend); and the atomic PNG
write of the report figures.

Used by :mod:`benchmarks.suite.figures`, :mod:`benchmarks.rl.figures` and
:mod:`benchmarks.rl.suite_figures`; it imports none of them (nor matplotlib at import: it draws on
the axes it is given).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

from benchmarks.core.files import write_atomic

__all__ = ["cost_violation_axes", "errbars", "interval_point", "save_figure"]


def save_figure(fig: Any, out: Path, name: str, names: list[str]) -> None:
    """Write ``fig`` as ``out / name`` (PNG at 100 dpi, after ``tight_layout``), atomically
    (:func:`benchmarks.core.files.write_atomic`), close it and append ``name`` to ``names``."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    write_atomic(out / name, buf.getvalue())
    names.append(name)


def interval_point(
    ax: Any,
    violation: float,
    violation_ci: tuple[float, float],
    cost: float,
    cost_ci: tuple[float, float],
    **kw: Any,
) -> None:
    """A point (``violation``, ``cost``) with its intervals as error bars (an interval that
    does not contain its point, e.g. a percentile one, draws no bar on that side)."""
    (vlo, vhi), (clo, chi) = violation_ci, cost_ci
    ax.errorbar(violation, cost,
                xerr=[[max(violation - vlo, 0.0)], [max(vhi - violation, 0.0)]],
                yerr=[[max(cost - clo, 0.0)], [max(chi - cost, 0.0)]], capsize=2, **kw)  # fmt: skip


def errbars(ax: Any, s: Any, **kw: Any) -> None:
    """A point with its violation (x, 95% Wilson) and cost (y, 95% t) intervals; ``s`` has
    ``violation``, ``violation_wilson95``, ``cost_mean`` and ``cost_ci95`` (a
    :class:`~benchmarks.evaluate.Score`, an aggregate of seeds, a point of the suite)."""
    interval_point(ax, s.violation, s.violation_wilson95, s.cost_mean, s.cost_ci95, **kw)


def cost_violation_axes(ax: Any, xi: float, title: str) -> None:
    """Finish a cost-against-violation panel: the target ``1 - xi`` (a red dotted line), a log
    cost axis, violation frequencies from 0 to 1, the labels, ``title``, a grid and a legend."""
    ax.axvline(1 - xi, color="r", ls=":", lw=1, label=f"1 - xi = {1 - xi:.2f}")
    ax.set_yscale("log")
    ax.set_xlim(-0.02, 1.02)
    ax.set_xlabel("per-step violation frequency (95% Wilson interval)")
    ax.set_ylabel("mean episode cost (95% interval), log scale")
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
