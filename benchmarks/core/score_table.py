"""The results table's row of a score: the columns every report of a scored policy shares
(:func:`benchmarks.evaluate.describe_score`, the RL comparison's REPORT.md)."""

from __future__ import annotations

from typing import Any

__all__ = ["TABLE_HEADER", "fmt_steps", "fmt_time", "row_fields", "table", "table_row"]


def fmt_steps(n: int) -> str:
    """Three significant digits: 2500608 -> '2.5M', 60006 -> '60k', 1056 -> '1.06k'."""
    if n >= 1_000_000:
        return f"{n / 1e6:.3g}M"
    if n >= 1000:
        return f"{n / 1e3:.3g}k"
    return str(n)


def fmt_time(seconds: float) -> str:
    """Microseconds with one decimal, or seconds from 1 s on."""
    return f"{seconds * 1e6:.1f}" if seconds < 1 else f"{seconds:.3g} s"


def row_fields(r: Any) -> list[Any]:
    """The common columns of a row: ``r`` has a ``name`` and a ``score`` (a controller, a
    trained seed with its ``run`` record) or is an aggregate with the score's fields."""
    s = r.score if hasattr(r, "score") else r
    source = getattr(r, "run", r)  # a trained seed's training record
    steps = getattr(source, "timesteps", 0)
    train = getattr(source, "train_time_s", 0.0)
    return [r.name, s.episodes, s.cost_mean, s.cost_ci95, s.cost_median, s.violation,
            s.violation_wilson95, s.diverged, steps, train, s.decision_time_batched_s,
            s.decision_time_single_s]  # fmt: skip


TABLE_HEADER = [
    "| controller | episodes | mean episode cost (95% CI) | median cost | violation frequency "
    "(95% Wilson) | diverged | training steps | training time (s) | decision time per state, "
    "batched / single (us) |",
    "|---|---|---|---|---|---|---|---|---|",
]


def table_row(r: Any) -> str:
    """One line of the results table (:data:`TABLE_HEADER`)."""
    name, eps, mean, (lo, hi), median, v, (vlo, vhi), div, steps, train, dtb, dts = row_fields(r)
    return (
        f"| {name} | {eps} | {mean:.4g} ({lo:.4g} to {hi:.4g}) | {median:.4g} | {v:.3f} "
        f"({vlo:.3f}-{vhi:.3f}) | {div} | {fmt_steps(steps) if steps else '-'} | {train:.0f} | "
        f"{fmt_time(dtb)} / {fmt_time(dts)} |"
    )


def table(rows: list[Any]) -> list[str]:
    """The results table of ``rows``: :data:`TABLE_HEADER` and one :func:`table_row` each."""
    return [*TABLE_HEADER, *(table_row(r) for r in rows)]
