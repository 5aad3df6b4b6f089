"""The pieces shared by the cost-against-violation figures (benchmarks/figure_parts.py): one
point with its intervals and one styling of the axes, used by the suite's, the RL comparison's
and the RL suite's figures instead of a copy in each (issue 32)."""

from __future__ import annotations

import ast
from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest
from test_structure import modules

from benchmarks.core.figures import cost_violation_axes, errbars, interval_point
from benchmarks.rl import figures as rl_figures
from benchmarks.rl import suite_figures as rl_suite_figures
from benchmarks.suite import figures as suite_figures

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


@pytest.fixture
def ax():
    fig, ax = plt.subplots()
    yield ax
    plt.close(fig)


def bar_segments(ax) -> list[np.ndarray]:
    """The segments of the error bars drawn on ``ax`` (x bar first, then y bar)."""
    return [np.asarray(seg) for c in ax.collections for seg in c.get_segments()]


def test_a_point_gets_its_two_intervals_as_bars(ax):
    interval_point(ax, 0.3, (0.2, 0.5), 10.0, (8.0, 13.0), fmt="o")
    x_bar, y_bar = bar_segments(ax)
    np.testing.assert_allclose(x_bar, [[0.2, 10.0], [0.5, 10.0]])
    np.testing.assert_allclose(y_bar, [[0.3, 8.0], [0.3, 13.0]])


def test_an_interval_beside_its_point_draws_no_bar_on_that_side(ax):
    """A percentile interval need not contain its point; matplotlib refuses negative bars."""
    interval_point(ax, 0.1, (0.2, 0.5), 10.0, (11.0, 13.0), fmt="o")
    x_bar, y_bar = bar_segments(ax)
    np.testing.assert_allclose(x_bar, [[0.1, 10.0], [0.5, 10.0]])
    np.testing.assert_allclose(y_bar, [[0.1, 10.0], [0.1, 13.0]])


def test_errbars_reads_a_scores_fields(ax):
    s = SimpleNamespace(violation=0.4, violation_wilson95=(0.35, 0.45), cost_mean=2.0,
                        cost_ci95=(1.5, 2.5))  # fmt: skip
    errbars(ax, s, fmt="s", label="a controller")
    x_bar, y_bar = bar_segments(ax)
    np.testing.assert_allclose(x_bar, [[0.35, 2.0], [0.45, 2.0]])
    np.testing.assert_allclose(y_bar, [[0.4, 1.5], [0.4, 2.5]])


def test_the_axes_of_a_cost_violation_panel(ax):
    ax.plot([0.1, 0.5], [1.0, 100.0], label="a curve")
    cost_violation_axes(ax, 0.9, "a task")
    assert ax.get_yscale() == "log" and ax.get_xlim() == (-0.02, 1.02)
    assert "violation frequency" in ax.get_xlabel() and "cost" in ax.get_ylabel()
    assert ax.get_title() == "a task"
    (target,) = [line for line in ax.lines if line.get_label().startswith("1 - xi")]
    np.testing.assert_allclose(target.get_xdata(), [0.1, 0.1])
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["a curve", "1 - xi = 0.10"]


def test_the_figure_modules_share_the_pieces():
    """No figure module keeps its own copy of the error bars (``_errbars`` once twinned
    ``errbars``): the three use figure_parts'."""
    assert rl_figures.errbars is suite_figures.errbars is rl_suite_figures.errbars is errbars
    assert suite_figures.cost_violation_axes is rl_suite_figures.cost_violation_axes
    defined = [
        f"{name}.{node.name}"
        for name, path in modules("benchmarks").items()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
        if isinstance(node, ast.FunctionDef) and node.name.strip("_").endswith("errbars")
    ]
    assert defined == ["benchmarks.core.figures.errbars"], defined
