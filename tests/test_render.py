"""The render() picture: frames, reuse of the figure, what the artists say, divergence, RecordVideo.

The facts of the picture are read from the matplotlib artists (legend texts, line data, tick
locations), not from pixels; pixels are compared only between two renders of the same history.
The macro example's band is typed in from section 6 of the paper (``2 + 0.5 k <= x(2) <= 5 +
0.5 k``), not taken from the model.
"""

from __future__ import annotations

import dataclasses
import warnings

import gymnasium as gym
import numpy as np
import pytest
from conftest import UNSHOWN, raises_naming

import sdjls_gym  # noqa: F401  (registers the ids)
from sdjls_gym import SDJLSEnv
from sdjls_gym.render import PAD, VIEW_CAP, EpisodeRenderer, render_episode, state_labels
from sdjls_gym.systems.macro import PAPER_K, macro

HORIZON = 20
INCOME_NAMES = ("income (k-1)", "income")


def _lower(k):
    return 2.0 + 0.5 * np.asarray(k, dtype=np.float64)  # paper, section 6


def _upper(k):
    return 5.0 + 0.5 * np.asarray(k, dtype=np.float64)


def _macro_with_state_names():
    """The macro model with state names (a field another change adds to SDJLSModel)."""
    model = macro()
    if "state_names" in {f.name for f in dataclasses.fields(model)}:
        return dataclasses.replace(model, state_names=INCOME_NAMES)
    object.__setattr__(model, "state_names", INCOME_NAMES)  # the model is a frozen dataclass
    return model


def _episode(policy, seed=0, **make_kwargs):
    """Run one episode with render_mode="rgb_array"; return the env, the frames and the history."""
    env = gym.make("SDJLS-Macro-v0", render_mode="rgb_array", **make_kwargs)
    _, info = env.reset(seed=seed)
    frames, xs, modes, violated = [env.render()], [info["state"]], [info["mode"]], [False]
    while True:
        *_, terminated, truncated, info = env.step(policy(info).astype(np.float32))
        frames.append(env.render())
        xs.append(info["state"])
        modes.append(info["mode"])
        violated.append(bool(info["violations"].any()))
        if terminated or truncated:
            break
    return env, frames, np.array(xs), np.array(modes), np.array(violated)


def _paper_feedback(info):
    return np.clip(PAPER_K[info["mode"]] @ info["state"], -200.0, 200.0)


def _zero_input(info):
    return np.zeros(1)


def _legend_texts(renderer):
    return [t.get_text() for t in renderer.ax.get_legend().get_texts()]


# --------------------------------------------------------------------------- frames


def test_frame_shape_dtype_and_something_drawn():
    env, frames, *_ = _episode(_paper_feedback)
    for frame in frames:
        assert frame.shape == (400, 640, 3)  # multiples of 16: no resizing by video encoders
        assert frame.dtype == np.uint8
        assert frame.std() > 0
    assert not np.array_equal(frames[0], frames[-1])  # the picture follows the episode


@pytest.mark.parametrize("policy", [_paper_feedback, _zero_input], ids=["feedback", "diverging"])
def test_reused_figure_gives_the_fresh_picture(policy):
    """Every frame of the env's reused figure equals a fresh figure's picture of that history.

    The diverging episode changes the y-limits and the legend on the way (background redraws).
    """
    env, frames, xs, modes, _ = _episode(policy)
    bound = env.unwrapped.divergence_bound
    for k, frame in enumerate(frames):
        fresh = render_episode(env.unwrapped.model, xs[: k + 1], modes[: k + 1], HORIZON, bound)
        np.testing.assert_array_equal(frame, fresh, err_msg=f"frame at k = {k}")
    # after a reset the reused figure shows the new episode as a fresh one would
    _, info = env.reset(seed=5)
    fresh = render_episode(env.unwrapped.model, info["state"][None], [info["mode"]], HORIZON, bound)
    np.testing.assert_array_equal(env.render(), fresh)


def test_frames_do_not_depend_on_the_order_they_are_drawn_in():
    model = macro()
    _, _, xs, modes, _ = _episode(_zero_input)
    renderer = EpisodeRenderer(model, HORIZON, 1e6)
    late = renderer.frame(xs, modes)
    early = renderer.frame(xs[:3], modes[:3])  # smaller y-range: background redrawn
    np.testing.assert_array_equal(early, render_episode(model, xs[:3], modes[:3], HORIZON, 1e6))
    np.testing.assert_array_equal(renderer.frame(xs, modes), late)


def test_pickled_env_renders_the_same_frame():
    import pickle

    env = gym.make("SDJLS-Macro-v0", render_mode="rgb_array")
    env.reset(seed=1)
    env.step(np.zeros(1, dtype=np.float32))
    frame = env.render()
    clone = pickle.loads(pickle.dumps(env.unwrapped))
    np.testing.assert_array_equal(clone.render(), frame)


# --------------------------------------------------------------------------- what the picture says


def test_state_names_label_the_lines_and_the_band():
    model = _macro_with_state_names()
    assert state_labels(model) == list(INCOME_NAMES)
    renderer = EpisodeRenderer(model, HORIZON)
    renderer.frame([[2.0, 2.0], [2.0, 3.0]], [0, 1])
    texts = _legend_texts(renderer)
    assert texts[:2] == list(INCOME_NAMES)
    band = [t for t in texts if "band" in t]
    # one band, on x(2) = income only (both rows of G constrain x(2) alone), named with its rows
    assert len(band) == 1
    assert band[0].startswith("band on income\n") and "(k-1)" not in band[0]
    assert "rows 0, 1 of G x ≤ H_k" in band[0]


def test_without_state_names_the_states_are_x1_xn():
    model = macro()
    if getattr(model, "state_names", None) is not None:
        model = dataclasses.replace(model, state_names=None)
    assert state_labels(model) == ["x(1)", "x(2)"]


def test_band_is_drawn_on_the_paper_bounds_in_the_colour_of_its_state():
    from matplotlib.colors import to_rgba

    renderer = EpisodeRenderer(macro(), HORIZON)
    renderer.frame([[2.0, 2.0]], [0])
    dashed = [
        line
        for line in renderer.ax.get_lines()
        if line.get_linestyle() == "--" and line.get_visible()
    ]
    k = np.arange(HORIZON + 1)
    assert len(dashed) == 2
    np.testing.assert_allclose(sorted(line.get_ydata()[0] for line in dashed), [2.0, 5.0])
    ys = sorted((line.get_ydata() for line in dashed), key=lambda y: y[0])
    np.testing.assert_allclose(ys[0], _lower(k))
    np.testing.assert_allclose(ys[1], _upper(k))
    income_colour = to_rgba(renderer.state_lines[1].get_color())
    for line in dashed:
        assert to_rgba(line.get_color()) == income_colour


def test_rows_that_mix_states_are_said_and_one_sided_bounds_named(other_model):
    """G of the other model: x(1) <= 1 + 0.1 k, -x(2) <= 1, x(1) + x(2) + x(3) <= 2 - 0.05 k."""
    renderer = EpisodeRenderer(other_model, 7)
    renderer.frame(np.zeros((1, 3)), [0])
    texts = _legend_texts(renderer)
    assert "upper bound on x(1)\n(row 0 of G x ≤ H_k)" in texts
    assert "lower bound on x(2)\n(row 1 of G x ≤ H_k)" in texts
    assert not any("x(3)" in t and "bound" in t for t in texts)
    notes = [t.get_text() for t in renderer.figure.texts]
    assert any(t.startswith("row 2 of G x ≤ H_k\nmixes states") for t in notes)


def test_k_ticks_are_integers_and_modes_are_named():
    renderer = EpisodeRenderer(macro(), HORIZON)
    renderer.frame([[2.0, 2.0], [2.5, 3.0], [3.0, 3.5]], [0, 2, 1])
    for ax in (renderer.ax, renderer.ax_mode):
        lo, hi = ax.get_xlim()
        ticks = [t for t in ax.xaxis.get_majorticklocs() if lo <= t <= hi]
        assert len(ticks) >= 3
        assert all(float(t).is_integer() for t in ticks)
        assert ticks[0] == 0 and ticks[-1] == HORIZON  # both ends of the episode are labelled
    lo, hi = renderer.ax.get_xlim()
    assert lo <= 0 and HORIZON <= hi < HORIZON + 1  # the horizon, not the steps so far
    labels = [t.get_text() for t in renderer.ax_mode.get_yticklabels()]
    assert labels == ["normal", "boom", "slump"]
    np.testing.assert_array_equal(renderer.mode_line.get_ydata(), [0, 2, 1])


def test_violations_are_marked_where_the_env_reports_them():
    env, _, xs, modes, violated = _episode(_paper_feedback)  # K alone leaves the band
    assert violated[1:].any() and not violated[0]
    renderer = EpisodeRenderer(env.unwrapped.model, HORIZON)
    renderer.frame(xs, modes)
    marks_k, marks_y = renderer.violation_marks.get_data()
    # both rows constrain x(2): one mark per violated step, on x(2)
    np.testing.assert_array_equal(marks_k, np.flatnonzero(violated))
    k = np.flatnonzero(violated)
    outside = (xs[k, 1] < _lower(k)) | (xs[k, 1] > _upper(k))
    assert outside.all()
    y0, y1 = renderer.ax.get_ylim()
    in_view = (y0 < xs[k, 1]) & (xs[k, 1] < y1)
    assert in_view.any()
    np.testing.assert_array_equal(marks_y[in_view], xs[k, 1][in_view])  # on the point itself
    assert np.all((y0 < marks_y) & (marks_y < y1))  # the others at the edge
    assert any(t.startswith("violates") for t in _legend_texts(renderer))


def test_no_violation_no_violation_entry():
    renderer = EpisodeRenderer(macro(), HORIZON)
    renderer.frame([[2.0, 3.0], [3.0, 3.0]], [0, 0])
    assert renderer.violation_marks.get_data()[0].size == 0
    assert not any("violates" in t for t in _legend_texts(renderer))
    assert not renderer.out_line.get_visible()


# --------------------------------------------------------------------------- divergence


def test_diverging_episode_keeps_the_band_in_view_and_marks_the_step():
    env, _, xs, modes, _ = _episode(_zero_input)
    assert np.max(np.abs(xs[-1])) > 1e6  # zero input: the episode diverges (terminated)
    renderer = EpisodeRenderer(env.unwrapped.model, HORIZON, 1e6)
    renderer.frame(xs, modes)
    # the band spans [2, 15] over the horizon; the axes stay within VIEW_CAP widths of it
    lo, hi, width = 2.0, _upper(HORIZON), _upper(HORIZON) - 2.0
    y0, y1 = renderer.ax.get_ylim()
    reach = (VIEW_CAP + 2 * PAD * (1 + 2 * VIEW_CAP)) * width
    assert lo - reach <= y0 and y1 <= hi + reach
    assert y1 - y0 < 10 * width  # not autoscaled to 1e6
    # the first step with a state outside the view is marked by a red line and named
    beyond = (xs < lo - VIEW_CAP * width) | (xs > hi + VIEW_CAP * width)
    k_out = int(np.argmax(beyond.any(axis=1)))
    assert renderer.out_line.get_visible()
    assert list(renderer.out_line.get_xdata()) == [k_out, k_out]
    note = renderer.out_text.get_text()
    assert renderer.out_text.get_visible()
    assert f"k = {k_out}: " in note and "leaves the plot" in note
    k_div = int(np.argmax(np.max(np.abs(xs), axis=1) > 1e6))
    assert f"k = {k_div}: diverged" in note
    # points beyond the view are drawn at its edges, and the legend says so
    n_edge = sum(len(m.get_offsets()) for m in renderer.edge_marks.values())
    assert n_edge == int(beyond.sum())
    assert "beyond the plot (at the edge)" in _legend_texts(renderer)


def test_non_finite_states_are_marked_without_warnings():
    xs = np.array([[2.0, 2.0], [3.0, 4.0], [np.inf, -np.inf], [np.nan, np.nan]])
    renderer = EpisodeRenderer(macro(), HORIZON, 1e6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frame = renderer.frame(xs, [0, 1, 2, 0])
    assert frame.shape == (400, 640, 3)
    # +inf and NaN at the top edge, -inf at the bottom
    y0, y1 = renderer.ax.get_ylim()
    top, bottom = (renderer.edge_marks[side].get_offsets() for side in ("above", "below"))
    assert sorted(map(tuple, top[:, :1].tolist())) == [(2.0,), (3.0,), (3.0,)]
    assert bottom[:, 0].tolist() == [2.0]
    assert np.all((y0 < top[:, 1]) & (top[:, 1] < y1) & (top[:, 1] > bottom[:, 1].max()))
    note = renderer.out_text.get_text()
    assert "k = 2: income (k-1) is inf" in note and "k = 2: diverged" in note
    assert np.all(np.isfinite(renderer.ax.get_ylim()))


def test_divergence_inside_the_view_is_still_marked():
    """With a small divergence_bound the episode ends while the state is in the picture."""
    xs = np.array([[2.0, 2.0], [3.0, 4.0], [4.0, 12.0]])
    renderer = EpisodeRenderer(macro(), HORIZON, divergence_bound=10.0)
    renderer.frame(xs, [0, 0, 0])
    assert renderer.out_line.get_visible() and list(renderer.out_line.get_xdata()) == [2, 2]
    assert renderer.out_text.get_text().startswith("k = 2: diverged")


def test_without_a_band_the_view_follows_the_data(other_model):
    """A model whose G only mixes states: no band; the axes follow the data."""
    model = dataclasses.replace(other_model, G=[[1.0, 1.0, 1.0]], H0=[2.0], H_rate=[0.0])
    xs = np.array([[0.0, 0.0, 0.0], [300.0, -50.0, 10.0]])
    renderer = EpisodeRenderer(model, 7)
    renderer.frame(xs, [0, 1])
    y0, y1 = renderer.ax.get_ylim()
    assert y0 <= -50.0 and y1 >= 300.0 and y1 - y0 < 2 * 350.0
    assert not renderer.out_line.get_visible()


# --------------------------------------------------------------------------- arguments


@pytest.mark.parametrize("make", ["gym.make", "class"])
def test_human_render_mode_is_rejected_at_construction(make):
    """Before: gym.make accepted "human" (adding pygame's HumanRendering) and failed at reset."""
    with raises_naming(
        ValueError, ("render_mode", "rgb_array", "gymnasium.wrappers.RecordVideo"), "human"
    ):
        if make == "gym.make":
            gym.make("SDJLS-Macro-v0", render_mode="human")
        else:
            SDJLSEnv("macro", render_mode="human")


@pytest.mark.parametrize(
    ("render_mode", "error"),
    [
        ("ansi", ValueError),
        ("rgb_array_list", ValueError),
        ("RGB_ARRAY", ValueError),
        (1, TypeError),
        (np.array(["human"]), TypeError),
    ],
)
def test_other_render_modes_are_rejected(render_mode, error):
    with raises_naming(error, "render_mode", render_mode):
        gym.make("SDJLS-Macro-v0", render_mode=render_mode)


def test_render_before_reset_raises():
    with pytest.raises(RuntimeError, match="reset"):
        SDJLSEnv("macro", render_mode="rgb_array").render()


@pytest.mark.parametrize(
    ("xs", "modes", "error", "name", "value"),
    [
        ([[2.0, 2.0, 2.0]], [0], ValueError, "xs", (1, 3)),
        ([[2.0, "a"]], [0], TypeError, "xs", [[2.0, "a"]]),
        (np.zeros((0, 2)), [], ValueError, "xs", UNSHOWN),  # "xs has no rows"
        ([[2.0, 2.0]], [3], ValueError, "modes", [3]),
        ([[2.0, 2.0]], [0.0], TypeError, "modes", np.dtype("float64")),
        ([[2.0, 2.0]], [True], TypeError, "modes", np.dtype("bool")),
        ([[2.0, 2.0], [1.0, 1.0]], [0], ValueError, "modes", (1,)),
    ],
)
def test_bad_history_names_the_argument(xs, modes, error, name, value):
    with raises_naming(error, name, value):
        EpisodeRenderer(macro(), HORIZON).frame(xs, modes)


@pytest.mark.parametrize(
    ("kwargs", "error", "name", "value"),
    [
        ({"horizon": 0}, ValueError, "horizon", 0),
        ({"horizon": 2.0}, TypeError, "horizon", 2.0),
        ({"horizon": 5, "divergence_bound": -1.0}, ValueError, "divergence_bound", -1.0),
        ({"horizon": 5, "divergence_bound": True}, TypeError, "divergence_bound", True),
    ],
)
def test_bad_renderer_arguments_name_the_argument(kwargs, error, name, value):
    with raises_naming(error, name, value):
        EpisodeRenderer(macro(), **kwargs)


# --------------------------------------------------------------------------- video


def test_record_video_writes_the_episode(tmp_path):
    moviepy = pytest.importorskip("moviepy")
    env = gym.wrappers.RecordVideo(
        gym.make("SDJLS-Macro-v0", render_mode="rgb_array"),
        str(tmp_path / "videos"),
        episode_trigger=lambda episode: True,
        disable_logger=True,
    )
    _, info = env.reset(seed=0)
    steps = 0
    while True:
        *_, terminated, truncated, info = env.step(_paper_feedback(info).astype(np.float32))
        steps += 1
        if terminated or truncated:
            break
    env.close()
    videos = sorted((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0
    clip = moviepy.VideoFileClip(str(videos[0]))
    try:
        assert tuple(clip.size) == (640, 400)
        assert clip.fps == env.metadata["render_fps"]
        assert round(clip.duration * clip.fps) == steps + 1  # the reset frame and one per step
    finally:
        clip.close()
