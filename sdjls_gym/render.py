"""Matplotlib pictures of an episode (used by ``render_mode="rgb_array"``)."""

from __future__ import annotations

import numpy as np

from sdjls_gym.model import SDJLSModel


def render_episode(
    model: SDJLSModel, xs: np.ndarray, modes: np.ndarray, horizon: int
) -> np.ndarray:
    """Draw the states against the constraint band and the mode sequence.

    Rows of ``G`` with a single nonzero entry ``G[j, i]`` are drawn as bounds
    ``x(i) <= H_k[j] / G[j, i]`` (or ``>=`` for a negative entry) on state component ``i``.

    Parameters
    ----------
    xs : (k+1, n) states so far
    modes : (k+1,) modes so far

    Returns
    -------
    (height, width, 3) uint8 RGB image
    """
    # A Figure with its own Agg canvas: no pyplot, and the global backend is left alone.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.8), dpi=80)
    canvas = FigureCanvasAgg(fig)
    ax_x, ax_m = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ks = np.arange(len(xs))
    band_k = np.arange(horizon + 1)
    H = model.H(band_k)
    colors = [f"C{i}" for i in range(model.n)]
    for i in range(model.n):
        ax_x.plot(ks, xs[:, i], "-o", ms=3, color=colors[i], label=f"x({i + 1})")
    for j, row in enumerate(model.G):
        nz = np.flatnonzero(row)
        if nz.size == 1:
            i = int(nz[0])
            ax_x.plot(band_k, H[:, j] / row[i], "--", color=colors[i], lw=1)
    ax_x.set_ylabel("state")
    ax_x.legend(loc="upper left", fontsize=8)
    ax_x.set_title("SDJLS episode (dashed: constraint band)")
    ax_m.step(ks, modes, where="post", color="k")
    ax_m.set_yticks(range(model.N), model.mode_names, fontsize=7)
    ax_m.set_xlabel("k")
    ax_m.set_xlim(0, horizon)
    fig.tight_layout()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
