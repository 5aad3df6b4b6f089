"""The scenario tree's plan of one decision, drawn once: ``docs/img/tree_plan.png``.

``python -m benchmarks.tree_picture`` asks :class:`controllers.ScenarioTreeController` for one
decision (by default on the paper's example, ``steps=3``, at ``x_0 = (2, 2)``, mode 0, ``k = 0``)
and draws the plan it returns (``info["plan"]``, a :class:`controllers.scenario_tree.TreePlan`):

* left, the tree: one disc per node at its stage, coloured by its mode, its area proportional to
  its path probability (printed beside it), an edge from each node to its parent;
* right, the plan against the band: for one state that rows of ``G`` bound alone, the band
  ``G x <= H_{k+t}`` at the times the plan covers, the state ``x_k`` at the root, and for every
  node the mean of the next state it plans (at time ``k + t + 1``, nodes of one stage spread
  sideways), with that node's tightened bounds (the band less the node's tightening, the
  chance constraint of section 4 with the node's covariance).

The figure is for the documentation; the command names its inputs in the title.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.commands import prog

DEFAULT_OUT = Path("docs/img/tree_plan.png")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``--env-id``, ``--steps``, ``--state``, ``--mode``, ``--k``, ``--out``."""
    parser = argparse.ArgumentParser(
        prog=prog("tree_picture"),
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--env-id", default="SDJLS-Macro-v0", help="a task of sdjls_gym.SUITE")
    parser.add_argument("--steps", type=int, default=3, help="stages of the tree")
    parser.add_argument(
        "--state", default=None, help="x_k as comma-separated numbers (default: the model's x0)"
    )
    parser.add_argument("--mode", type=int, default=0, help="the mode at the root")
    parser.add_argument("--k", type=int, default=0, help="the time of the root")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the PNG to write")
    args = parser.parse_args(argv)
    if args.state is not None:
        try:
            args.state = [float(v) for v in args.state.split(",")]
        except ValueError:
            parser.error(f"--state {args.state!r}: expected comma-separated numbers")
    if not args.out.parent.is_dir():
        parser.error(f"--out {str(args.out)!r}: the folder {str(args.out.parent)!r} does not exist")
    return args


def plan_of(env_id: str, steps: int, state: Any, mode: int, k: int) -> tuple[Any, Any, dict]:
    """``(task, plan, info)`` of one decision of the task's scenario-tree controller."""
    from controllers import ScenarioTreeController
    from sdjls_gym.systems import TASKS

    if env_id not in TASKS:
        raise ValueError(f"env_id = {env_id!r} is not a task; expected one of {sorted(TASKS)}")
    task = TASKS[env_id]
    ctrl = ScenarioTreeController(
        model=task.model, K=task.K, **task.rhc, steps=steps, horizon=task.horizon
    )
    x = task.model.x0 if state is None else np.asarray(state, dtype=np.float64)
    _, info = ctrl.act(x, mode, k)
    return task, info["plan"], info


def _tree_layout(plan: Any) -> np.ndarray:
    """A y position per node: leaves evenly spaced in depth-first order, parents centred."""
    size = plan.mode.size
    children: list[list[int]] = [[] for _ in range(size)]
    for i in range(1, size):
        children[int(plan.parent[i])].append(i)
    y = np.zeros(size)
    next_leaf = [0.0]

    def place(i: int) -> float:
        if not children[i]:
            y[i] = next_leaf[0]
            next_leaf[0] += 1.0
        else:
            y[i] = float(np.mean([place(c) for c in children[i]]))
        return y[i]

    place(0)
    return y.max() - y  # the first child on top


def _disc_area(probability: np.ndarray, scale: float = 900.0) -> np.ndarray:
    return 20.0 + scale * probability


def draw(task: Any, plan: Any, info: dict, out: Path) -> Path:
    """Draw ``plan`` (see the module docstring) into ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    model = task.model
    colors = matplotlib.color_sequences["tab10"]  # the colours of the tab10 colormap
    names = model.mode_names
    steps = int(plan.stage.max()) + 1
    fig, (ax_tree, ax_band) = plt.subplots(
        1, 2, figsize=(12.0, 5.2), gridspec_kw={"width_ratios": [1.0, 1.25]}
    )
    _draw_tree(ax_tree, plan, colors)
    handles = _draw_band(ax_band, model, plan, colors)
    ax_band.set_title("the plan against the band", fontsize=10)
    mode_handles = [
        Line2D([], [], marker="o", ls="", mfc=colors[m % 10], mec="black", ms=8,
               label=f"mode {m}: {names[m]}")
        for m in range(model.N)
    ]  # fmt: skip
    fig.legend(handles=mode_handles, loc="lower left", ncol=model.N, fontsize=8, frameon=False,
               bbox_to_anchor=(0.02, 0.0))  # fmt: skip
    ax_band.legend(handles=handles, loc="upper left", fontsize=8)
    x_text = ", ".join(f"{v:g}" for v in plan.mean[0])
    nu = ", ".join(f"{v:.3g}" for v in np.atleast_1d(info["nu"]))
    fig.suptitle(
        f"{task.env_id}: ScenarioTreeController(steps={steps}, xi={task.rhc['xi']:g}) at "
        f"x_k = ({x_text}), mode {int(plan.mode[0])} ({names[int(plan.mode[0])]}), k = {plan.k}: "
        f"applied offset nu = {nu}, rho = {info['rho']:.3g}, status {info['status']!r}",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.05, 1, 0.95))
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def _draw_tree(ax_tree: Any, plan: Any, colors: Any) -> None:
    """The tree: a disc per node at its stage, its path probability beside it."""
    steps = int(plan.stage.max()) + 1
    y = _tree_layout(plan)
    for i in range(1, plan.mode.size):
        p = int(plan.parent[i])
        ax_tree.plot([plan.stage[p], plan.stage[i]], [y[p], y[i]], color="0.6", lw=1, zorder=1)
    ax_tree.scatter(
        plan.stage, y, s=_disc_area(plan.probability), c=[colors[m % 10] for m in plan.mode],
        edgecolors="black", linewidths=0.6, zorder=2,
    )  # fmt: skip
    radius = np.sqrt(_disc_area(plan.probability)) / 2  # in points
    for i in range(plan.mode.size):
        ax_tree.annotate(
            f"{plan.probability[i]:.3f}", (plan.stage[i], y[i]), xytext=(radius[i] + 2, 4),
            textcoords="offset points", fontsize=8,
        )  # fmt: skip
    ax_tree.set_xticks(range(steps))
    ax_tree.set_xticklabels([f"t = {t}\n(k = {plan.k + t})" for t in range(steps)])
    ax_tree.set_xlim(-0.4, steps - 0.4)
    ax_tree.set_yticks([])
    ax_tree.set_title("the tree: nodes by stage, path probability beside each", fontsize=10)
    for side in ("left", "right", "top"):
        ax_tree.spines[side].set_visible(False)


def _draw_band(ax_band: Any, model: Any, plan: Any, colors: Any) -> list[Any]:
    """The plan against the band, for the first state that rows of ``G`` bound alone; the
    legend's handles (none when no state is bounded alone)."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from sdjls_gym.render import single_state_bounds, state_labels

    steps = int(plan.stage.max()) + 1
    times = plan.k + np.arange(steps + 1)
    bounds, _ = single_state_bounds(model, int(times[-1]))
    handles: list[Any] = []
    if not bounds:
        return handles
    b = bounds[0]
    i_state = b.state
    label = state_labels(model)[i_state]
    lo = b.lower[times] if b.lower is not None else None
    hi = b.upper[times] if b.upper is not None else None
    if lo is not None and hi is not None:
        ax_band.fill_between(times, lo, hi, step=None, color="tab:green", alpha=0.15, lw=0)
        handles.append(plt.Rectangle((0, 0), 1, 1, color="tab:green", alpha=0.15))
        handles[-1].set_label(f"band of {label}: G x <= H_k")
    for edge in (lo, hi):
        if edge is not None:
            ax_band.plot(times, edge, color="tab:green", lw=1)
    ax_band.scatter([plan.k], [plan.mean[0, i_state]], marker="s", color="black", zorder=4)
    handles.append(
        Line2D([], [], marker="s", color="black", ls="", label=f"x_k at the root ({label})")
    )
    # nodes of one stage side by side around k + t + 1
    xs = np.zeros(plan.mode.size)
    for t in range(steps):
        members = np.flatnonzero(plan.stage == t)
        spread = np.linspace(-0.3, 0.3, members.size) if members.size > 1 else np.zeros(1)
        xs[members] = plan.k + t + 1 + spread
    rows_lo = [j for j in b.rows if model.G[j, i_state] < 0]
    rows_hi = [j for j in b.rows if model.G[j, i_state] > 0]
    for i in range(plan.mode.size):
        g_hi = [(model.H(times[plan.stage[i] + 1])[j] - plan.tightening[i, j]) / model.G[j, i_state] for j in rows_hi]  # fmt: skip
        g_lo = [(model.H(times[plan.stage[i] + 1])[j] - plan.tightening[i, j]) / model.G[j, i_state] for j in rows_lo]  # fmt: skip
        for value in ([min(g_hi)] if g_hi else []) + ([max(g_lo)] if g_lo else []):
            ax_band.plot(
                [xs[i] - 0.1, xs[i] + 0.1], [value, value], color="tab:red", lw=1.5, zorder=5
            )
        ax_band.plot(
            [xs[int(plan.parent[i])] if i else plan.k, xs[i]],
            [plan.next_mean[int(plan.parent[i]), i_state] if i else plan.mean[0, i_state],
             plan.next_mean[i, i_state]],
            color="0.75", lw=0.8, zorder=1,
        )  # fmt: skip
    ax_band.scatter(
        xs, plan.next_mean[:, i_state], s=_disc_area(plan.probability, 400.0),
        c=[colors[m % 10] for m in plan.mode], edgecolors="black", linewidths=0.6, zorder=3,
    )  # fmt: skip
    handles.append(
        Line2D(
            [],
            [],
            color="tab:red",
            lw=1.2,
            label="a node's tightened bound (chance constraint)",
        )
    )
    handles.append(
        Line2D([], [], marker="o", ls="", mfc="white", mec="black", ms=9,
               label="a node's planned next-state mean (area: path probability)")
    )  # fmt: skip
    ax_band.set_ylabel(label)
    ax_band.set_xticks(times)
    ax_band.set_xlabel("k")
    return handles


def main(argv: list[str] | None = None) -> Path:
    """Draw the plan and write the PNG; returns its path."""
    args = parse_args(argv)
    task, plan, info = plan_of(args.env_id, args.steps, args.state, args.mode, args.k)
    out = draw(task, plan, info, args.out)
    print(f"wrote {out}: {plan.mode.size} nodes, status {info['status']}")
    return out


if __name__ == "__main__":
    main()
