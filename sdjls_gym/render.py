"""Matplotlib pictures of an episode: the states against the constraint band, and the modes.

:class:`EpisodeRenderer` builds one figure per environment. A frame updates only the artists
that depend on the episode (lines, markers, texts) and draws them over a cached picture of the
rest (axes, ticks, band, legend), which is redrawn only when the axis limits or the legend
change. A frame is a function of the history alone: a reused renderer and a fresh one give the
same picture.

What the picture shows:

* one line per state, named by ``model.state_names`` when the model has them, else
  ``x(1) .. x(n)``;
* for every state that rows of ``G`` constrain alone (``g x_i <= H_k[j]``), its bounds (dashed)
  and its band (shaded) in that state's colour, named in the legend; rows that mix states are
  listed in a note (their violations are still marked);
* red circles on the states of the violated rows at every step where ``G x_k <= H_k`` fails;
* y-limits around the band (widened by a quarter of its width, and in steps of a quarter to show
  the data, but never more than two band widths beyond it; without a band, the data up to
  ``divergence_bound``):
  points beyond are triangles at the edge; a red dashed line marks the first step that leaves
  the plot (or, when none does, the step where the episode diverged), and a red note names that
  step and the step of divergence (``max |x| > divergence_bound`` or a non-finite state);
* the mode sequence with the mode names, and integer ticks on ``k``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from sdjls_gym.model import SDJLSModel
from sdjls_gym.validation import check_array, check_int, check_positive

__all__ = [
    "EpisodeRenderer",
    "render_episode",
    "state_labels",
    "single_state_bounds",
    "FIGSIZE",
    "DPI",
]

#: Figure size in inches and resolution: 640 x 400 pixels, multiples of 16 for video codecs.
FIGSIZE = (8.0, 5.0)
DPI = 80

#: An entry of ``G`` counts as zero below this fraction of the largest entry of its row.
ROW_TOL = 1e-12
#: The view shows the band widened by this fraction of its width on each side, and widens in
#: steps of that size to show the data ...
VIEW_MARGIN = 0.25
#: ... extended to the data, but never more than this many band widths beyond the band.
VIEW_CAP = 2.0
#: Padding of the k axis on each side, in steps (markers at k = 0 and k = T stay whole).
K_PAD = 0.4
#: Padding of the y-limits around the view, as a fraction of its height (edge markers stay
#: visible).
PAD = 0.04


def state_labels(model: SDJLSModel) -> list[str]:
    """``model.state_names`` when the model has them, else ``["x(1)", ..., "x(n)"]``."""
    names = getattr(model, "state_names", None)
    if names is not None and len(names) == model.n:
        return [str(s) for s in names]
    return [f"x({i + 1})" for i in range(model.n)]


def row_states(G: np.ndarray) -> list[np.ndarray]:
    """The states each row of ``G`` involves: indices of entries above ``ROW_TOL`` of the row."""
    out = []
    for row in np.asarray(G, dtype=np.float64):
        scale = float(np.max(np.abs(row))) if row.size else 0.0
        out.append(np.flatnonzero(np.abs(row) > ROW_TOL * scale) if scale > 0 else np.array([]))
    return out


@dataclass(frozen=True)
class Bounds:
    """The bounds that single-state rows of ``G x <= H_k`` put on one state.

    Attributes
    ----------
    state : int
        The state ``i``.
    rows : tuple of int
        The rows of ``G`` that constrain ``x(i)`` alone.
    lower, upper : (K,) arrays or None
        ``max`` of the lower bounds and ``min`` of the upper bounds at ``k = 0 .. K-1``; None when
        no row bounds that side.
    """

    state: int
    rows: tuple[int, ...]
    lower: np.ndarray | None
    upper: np.ndarray | None


def single_state_bounds(model: SDJLSModel, k_max: int) -> tuple[list[Bounds], list[int]]:
    """The bands drawn for ``k = 0 .. k_max``, and the rows of ``G`` that mix states.

    A row ``j`` with one entry ``g = G[j, i]`` is the bound ``x(i) <= H_k[j] / g`` (``g > 0``) or
    ``x(i) >= H_k[j] / g`` (``g < 0``).

    Returns
    -------
    bounds : list of Bounds
        One per constrained state, in the order of the states.
    mixed : list of int
        Rows with two or more entries (0-based).
    """
    H = model.H(np.arange(k_max + 1))  # (k_max + 1, r)
    lower: dict[int, list[np.ndarray]] = {}
    upper: dict[int, list[np.ndarray]] = {}
    rows: dict[int, list[int]] = {}
    mixed = []
    for j, states in enumerate(row_states(model.G)):
        if states.size != 1:
            if states.size > 1:
                mixed.append(j)
            continue
        i = int(states[0])
        g = float(model.G[j, i])
        (upper if g > 0 else lower).setdefault(i, []).append(H[:, j] / g)
        rows.setdefault(i, []).append(j)
    bounds = [
        Bounds(
            state=i,
            rows=tuple(rows[i]),
            lower=np.max(lower[i], axis=0) if i in lower else None,
            upper=np.min(upper[i], axis=0) if i in upper else None,
        )
        for i in sorted(rows)
    ]
    return bounds, mixed


def _widen(lo: float, hi: float) -> tuple[float, float]:
    """``[lo, hi]`` made non-degenerate: a point gets a width of a tenth of its size (or 2)."""
    if hi - lo > 1e-12 * max(abs(lo), abs(hi)):
        return lo, hi
    half = 0.1 * abs(hi) if hi != 0 else 1.0
    return lo - half, hi + half


@dataclass(frozen=True)
class _Frame:
    """What one frame shows, computed from the history alone."""

    ks: np.ndarray  # (K+1,) time indices
    xs: np.ndarray  # (K+1, n) states
    modes: np.ndarray  # (K+1,) modes
    ylim: tuple[float, float]  # the axis limits
    edge: tuple[float, float]  # where points beyond the view are drawn
    k_max: int  # the last k on the axis
    violated: np.ndarray  # (K+1, n) bool: state i is in a violated row at step k
    above: np.ndarray  # (K+1, n) bool: beyond the top of the view (or NaN)
    below: np.ndarray  # (K+1, n) bool: beyond the bottom
    k_out: int | None  # first step with a state beyond the view
    k_diverged: int | None  # first step with max |x| > divergence_bound or a non-finite state

    @property
    def key(self) -> tuple:
        """What the cached background depends on: limits and legend entries."""
        beyond = bool(self.above.any() or self.below.any())
        return (self.ylim, self.k_max, bool(self.violated.any()), beyond)


class EpisodeRenderer:
    """One figure that draws an episode's history, frame after frame.

    Parameters
    ----------
    model : SDJLSModel
    horizon : int
        Episode length ``T``: the k axis shows ``0 .. T`` (more if the history is longer).
    divergence_bound : float, optional
        The env's termination threshold on ``max |x|`` (None: no threshold).

    Examples
    --------
    >>> import numpy as np
    >>> from sdjls_gym.systems.macro import macro
    >>> renderer = EpisodeRenderer(macro(), horizon=20)
    >>> frame = renderer.frame(np.array([[2.0, 2.0], [2.0, 3.5]]), np.array([0, 1]))
    >>> frame.shape, frame.dtype
    ((400, 640, 3), dtype('uint8'))
    """

    def __init__(
        self,
        model: SDJLSModel,
        horizon: int,
        divergence_bound: float | None = None,
    ) -> None:
        if not isinstance(model, SDJLSModel):
            raise TypeError(f"model is a {type(model).__name__}; expected an SDJLSModel")
        self.model = model
        self.horizon = check_int("horizon", horizon, low=1)
        self.divergence_bound = (
            math.inf
            if divergence_bound is None
            else check_positive("divergence_bound", divergence_bound)
        )
        self.labels = state_labels(model)
        self._row_states = row_states(model.G)
        self._bounds: tuple[int, list[Bounds], list[int]] = (-1, [], [])  # k_max, bands, mixed
        self._fig: Any = None
        self._key: tuple | None = None
        self._background: Any = None
        self._bands_for = -1

    # ------------------------------------------------------------------ pickling
    def __getstate__(self) -> dict[str, Any]:
        # the figure is rebuilt on the next frame; matplotlib canvases do not pickle cleanly
        state = self.__dict__.copy()
        state.update(_fig=None, _key=None, _background=None, _bands_for=-1)
        return state

    # ------------------------------------------------------------------ the data of a frame
    def _check_history(self, xs: Any, modes: Any) -> tuple[np.ndarray, np.ndarray]:
        model = self.model
        xs = check_array("xs", xs, shape=(None, model.n), finite=False, what="states x_0 .. x_K")
        if xs.shape[0] < 1:
            raise ValueError("xs has no rows; expected the states x_0 .. x_K, K >= 0")
        raw = np.asarray(modes)
        if raw.dtype.kind not in "iu":
            raise TypeError(f"modes has dtype {raw.dtype}; expected ints (one mode per state)")
        if raw.shape != (xs.shape[0],):
            raise ValueError(
                f"modes has shape {raw.shape}; expected ({xs.shape[0]},), one mode per state"
            )
        if raw.size and (raw.min() < 0 or raw.max() >= model.N):
            raise ValueError(f"modes = {raw.tolist()}; expected ints in [0, {model.N})")
        return xs, raw.astype(np.int64)

    def _frame_data(self, xs: np.ndarray, modes: np.ndarray) -> _Frame:
        model = self.model
        ks = np.arange(xs.shape[0])
        k_max = max(self.horizon, int(ks[-1]))
        finite = np.isfinite(xs)
        with np.errstate(invalid="ignore", over="ignore"):
            values = model.constraint_values(np.where(finite, xs, 0.0), ks)
            row_violated = (values > 0.0) & finite.all(axis=1, keepdims=True)
            big = ~finite.all(axis=1) | (
                np.max(np.abs(np.where(finite, xs, 0.0)), axis=1) > (self.divergence_bound)
            )
        violated = np.zeros(xs.shape, dtype=bool)
        for j, states in enumerate(self._row_states):
            violated[np.ix_(row_violated[:, j], states)] = True

        bounds, _ = self._bands(k_max)
        if bounds:  # the view is set by the band; x_0 is in it too
            ref = [xs[0][finite[0]]]
            ref += [b.lower for b in bounds if b.lower is not None]
            ref += [b.upper for b in bounds if b.upper is not None]
            lo, hi = _widen(
                min(float(np.min(r)) for r in ref if r.size),
                max(float(np.max(r)) for r in ref if r.size),
            )
            step = VIEW_MARGIN * (hi - lo)
            cap = (lo - VIEW_CAP * (hi - lo), hi + VIEW_CAP * (hi - lo))
            inside = finite & (xs >= cap[0]) & (xs <= cap[1])
            d_lo, d_hi = (xs[inside].min(), xs[inside].max()) if inside.any() else (lo, hi)
            # widened in whole steps (a quarter of the band), so the axes change rarely
            view = (
                max(cap[0], lo - step * max(1.0, math.ceil((lo - d_lo) / step))),
                min(cap[1], hi + step * max(1.0, math.ceil((d_hi - hi) / step))),
            )
        else:  # no band: the data, up to the divergence bound
            cap = (-self.divergence_bound, self.divergence_bound)
            inside = finite & (xs >= cap[0]) & (xs <= cap[1])
            view = (xs[inside].min(), xs[inside].max()) if inside.any() else (-1.0, 1.0)
            view = (float(view[0]), float(view[1]))
        view = _widen(*view)
        pad = PAD * (view[1] - view[0])
        below = (finite & (xs < view[0])) | (xs == -np.inf)
        above = (finite & (xs > view[1])) | (xs == np.inf) | np.isnan(xs)  # NaN: at the top
        beyond = (above | below).any(axis=1)
        return _Frame(
            ks=ks,
            xs=xs,
            modes=modes,
            ylim=(view[0] - pad, view[1] + pad),
            edge=view,
            k_max=k_max,
            violated=violated,
            above=above,
            below=below,
            k_out=int(np.argmax(beyond)) if beyond.any() else None,
            k_diverged=int(np.argmax(big)) if big.any() else None,
        )

    def _bands(self, k_max: int) -> tuple[list[Bounds], list[int]]:
        if self._bounds[0] != k_max:
            self._bounds = (k_max, *single_state_bounds(self.model, k_max))
        return self._bounds[1], self._bounds[2]

    # ------------------------------------------------------------------ the figure
    def _build(self) -> None:
        """Create the figure and every artist, once."""
        # a Figure with its own Agg canvas: no pyplot, the global backend is left alone
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.lines import Line2D
        from matplotlib.ticker import MaxNLocator

        fig = Figure(figsize=FIGSIZE, dpi=DPI)
        FigureCanvasAgg(fig)
        # fixed margins (no tight_layout per frame); the legend sits right of the axes
        fig.subplots_adjust(left=0.09, right=0.70, top=0.92, bottom=0.10, hspace=0.12)
        ax, ax_m = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
        # the episode's artists are "animated": canvas.draw() leaves them out of the cached
        # background, and frame() draws them over it
        n = self.model.n
        self.colors = [f"C{i % 10}" for i in range(n)]
        self.state_lines = [
            ax.plot([], [], "-o", ms=3, lw=1.5, color=self.colors[i], label=self.labels[i],
                    animated=True)[0]
            for i in range(n)
        ]  # fmt: skip
        self.violation_marks = ax.plot(
            [], [], "o", ms=9, mfc="none", mec="red", mew=1.5, animated=True,
            label="violates G x ≤ H_k",
        )[0]  # fmt: skip
        self.edge_marks = {
            side: ax.scatter([], [], marker=marker, s=40, zorder=4, animated=True,
                             clip_on=False)
            for side, marker in (("above", "^"), ("below", "v"))
        }  # fmt: skip
        self._edge_proxy = Line2D([], [], marker="^", ls="none", color="0.4")  # legend only
        self.out_line = ax.axvline(0, color="red", ls="--", lw=1.2, animated=True, visible=False)
        # the note on leaving the plot / diverging: right of the axes, under the legend
        self.out_text = fig.text(
            0.72, 0.56, "", color="red", fontsize=8, va="top", animated=True, visible=False
        )
        self.mode_line = ax_m.plot(
            [], [], "-o", ms=3, color="k", drawstyle="steps-post", animated=True
        )[0]
        self.title = fig.text(0.09, 0.96, "", fontsize=10, va="center", animated=True)
        ax.set_ylabel("state")
        ax.grid(True, alpha=0.3)
        ax_m.set_yticks(range(self.model.N), self.model.mode_names, fontsize=8)
        ax_m.set_ylim(-0.5, self.model.N - 0.5)
        ax_m.set_ylabel("mode")
        ax_m.set_xlabel("k")
        ax_m.grid(True, axis="x", alpha=0.3)
        # integer k at round steps (1, 2, 5, 10, 20, ...); shared with ax
        ax_m.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
        self.ax, self.ax_mode, self._fig = ax, ax_m, fig
        self._band_artists: list[Any] = []
        self._band_handles: list[tuple[Any, str]] = []
        self._legend = None
        self._mixed_note = None

    def _draw_bands(self, k_max: int) -> None:
        """(Re)draw the bands for ``k = 0 .. k_max`` and the note on rows that mix states."""
        for artist in self._band_artists:
            artist.remove()
        self._band_artists, self._band_handles = [], []
        bounds, mixed = self._bands(k_max)
        band_k = np.arange(k_max + 1)
        for b in bounds:
            color, name = self.colors[b.state], self.labels[b.state]
            rows = ", ".join(str(j) for j in b.rows)
            for side in (b.lower, b.upper):
                if side is not None:
                    self._band_artists += self.ax.plot(band_k, side, "--", lw=1, color=color)
            if b.lower is not None and b.upper is not None:
                fill = self.ax.fill_between(band_k, b.lower, b.upper, color=color, alpha=0.15, lw=0)
                self._band_artists.append(fill)
                handle, label = fill, f"band on {name}"
            else:
                handle = self._band_artists[-1]
                label = f"{'lower' if b.upper is None else 'upper'} bound on {name}"
            self._band_handles.append(
                (handle, f"{label}\n(row{'s' * (len(b.rows) > 1)} {rows} of G x ≤ H_k)")
            )
        if self._mixed_note is not None:
            self._mixed_note.remove()
            self._mixed_note = None
        if mixed:
            rows = ", ".join(str(j) for j in mixed)
            plural = len(mixed) > 1
            self._mixed_note = self._fig.text(
                0.72, 0.34, f"row{'s' * plural} {rows} of G x ≤ H_k\nmix{'es' * (not plural)} "
                f"states: no band drawn,\nviolations marked", fontsize=8, va="top",
            )  # fmt: skip
        self._bands_for = k_max

    def _draw_background(self, f: _Frame) -> None:
        """Limits, bands and legend of frame ``f``: the picture under the episode's artists."""
        if self._bands_for != f.k_max:
            self._draw_bands(f.k_max)
        self.ax.set_xlim(-K_PAD, f.k_max + K_PAD)
        self.ax.set_ylim(*f.ylim)
        handles = [(line, line.get_label()) for line in self.state_lines] + self._band_handles
        if f.violated.any():
            handles.append((self.violation_marks, "violates G x ≤ H_k"))
        if f.above.any() or f.below.any():
            handles.append((self._edge_proxy, "beyond the plot (at the edge)"))
        if self._legend is not None:
            self._legend.remove()
        self._legend = self.ax.legend(
            [h for h, _ in handles], [s for _, s in handles], loc="upper left",
            bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False, borderaxespad=0.0,
        )  # fmt: skip
        self._key = f.key

    def _set_artists(self, f: _Frame) -> None:
        """Put the episode's data into the artists."""
        for i, line in enumerate(self.state_lines):
            line.set_data(f.ks, f.xs[:, i])
        k_idx, i_idx = np.nonzero(f.violated)
        y = np.clip(f.xs[k_idx, i_idx], *f.edge)
        self.violation_marks.set_data(f.ks[k_idx], np.nan_to_num(y, nan=f.edge[1]))
        for side, mask, y_edge in (("above", f.above, f.edge[1]), ("below", f.below, f.edge[0])):
            k_idx, i_idx = np.nonzero(mask)
            marks = self.edge_marks[side]
            marks.set_offsets(np.column_stack([f.ks[k_idx], np.full(k_idx.size, y_edge)]))
            marks.set_color([self.colors[i] for i in i_idx])
        self.mode_line.set_data(f.ks, f.modes)
        self.title.set_text(f"SDJLS episode, k = {int(f.ks[-1])} of {self.horizon}")
        notes = []
        if f.k_out is not None:
            i = int(np.argmax(f.above[f.k_out] | f.below[f.k_out]))
            x = f.xs[f.k_out, i]
            what = f"= {x:.3g}" if np.isfinite(x) else f"is {x}"
            notes.append(f"k = {f.k_out}: {self.labels[i]} {what}\nleaves the plot")
        if f.k_diverged is not None:
            notes.append(
                f"k = {f.k_diverged}: diverged, episode\nterminated "
                f"(max |x| > {self.divergence_bound:.3g})"
            )
        k_mark = f.k_out if f.k_out is not None else f.k_diverged
        for artist in (self.out_line, self.out_text):
            artist.set_visible(k_mark is not None)
        if k_mark is not None:  # a red line at the first step the picture loses the state
            self.out_line.set_xdata([k_mark, k_mark])
            self.out_text.set_text("\n".join(notes))

    def _dynamic_artists(self) -> list[Any]:
        return [
            *self.state_lines,
            self.violation_marks,
            self.edge_marks["above"],
            self.edge_marks["below"],
            self.out_line,
            self.out_text,
            self.mode_line,
            self.title,
        ]

    # ------------------------------------------------------------------ public
    @property
    def figure(self) -> Any:
        """The matplotlib ``Figure`` (None before the first frame)."""
        return self._fig

    def frame(self, xs: np.ndarray, modes: np.ndarray) -> np.ndarray:
        """The picture of the history ``x_0 .. x_K``, ``theta_0 .. theta_K``.

        Parameters
        ----------
        xs : (K+1, n) states so far (non-finite entries allowed: a diverged episode)
        modes : (K+1,) int modes so far

        Returns
        -------
        (400, 640, 3) uint8 RGB image
        """
        xs, modes = self._check_history(xs, modes)
        f = self._frame_data(xs, modes)
        if self._fig is None:
            self._build()
        canvas = self._fig.canvas
        if self._key != f.key:
            self._draw_background(f)
            canvas.draw()  # animated artists are left out
            self._background = canvas.copy_from_bbox(self._fig.bbox)
        else:
            canvas.restore_region(self._background)
        self._set_artists(f)
        for artist in self._dynamic_artists():
            if artist.get_visible():
                self._fig.draw_artist(artist)
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        """Free the figure (the next frame builds a new one)."""
        self._fig, self._key, self._background, self._bands_for = None, None, None, -1


def render_episode(
    model: SDJLSModel,
    xs: np.ndarray,
    modes: np.ndarray,
    horizon: int,
    divergence_bound: float | None = None,
) -> np.ndarray:
    """The picture of one history with a fresh figure (see :class:`EpisodeRenderer`).

    Parameters
    ----------
    xs : (K+1, n) states so far
    modes : (K+1,) modes so far

    Returns
    -------
    (400, 640, 3) uint8 RGB image
    """
    return EpisodeRenderer(model, horizon, divergence_bound).frame(xs, modes)
