"""SDJLSModel: the paper's example, validation, (de)serialization, immutability, dynamics.

Expected numbers come from the paper (typed into ``conftest.py``) or are computed by hand in
the test from the formulas of section 2; nothing is copied from the code under test.
"""

from __future__ import annotations

import copy
import dataclasses
import pickle
import re

import numpy as np
import pytest

import sdjls_gym
from sdjls_gym import InvalidModelError, SDJLSModel, load_model, save_model

# --------------------------------------------------------------------------- the paper's example


def test_macro_preset_is_section_6_of_the_paper(paper):
    model = sdjls_gym.macro()

    assert (model.N, model.n, model.m, model.p, model.r) == (3, 2, 1, 2, 2)
    np.testing.assert_array_equal(model.A, paper.A)
    np.testing.assert_array_equal(model.B, np.broadcast_to(paper.B, (3, 2, 1)))
    np.testing.assert_array_equal(model.P_in, paper.lam)
    np.testing.assert_array_equal(model.P_out, paper.mu)
    np.testing.assert_array_equal(model.G, paper.G)
    np.testing.assert_array_equal(model.E, np.broadcast_to(np.eye(2), (3, 2, 2)))  # E = I
    np.testing.assert_array_equal(model.W, np.eye(2))  # w_k ~ N(0, I_2)
    np.testing.assert_array_equal(model.Q, paper.Q)
    np.testing.assert_array_equal(model.R, paper.R)
    np.testing.assert_array_equal(model.x0, paper.x0)
    assert model.mode0 == 0  # the paper's mode 1, "normal"
    assert model.mode_names == ("normal", "boom", "slump")


def test_macro_band_is_H_k_of_the_paper(paper):
    model = sdjls_gym.macro()
    for k in range(paper.horizon + 1):
        np.testing.assert_allclose(model.H(k), paper.H(k), rtol=0, atol=1e-12)
    # batched k
    ks = np.arange(paper.horizon + 1)
    np.testing.assert_allclose(model.H(ks), np.array([paper.H(k) for k in ks]), atol=1e-12)
    # the band 2 + 0.5 k <= x(2) <= 5 + 0.5 k, with its edges inside
    for k, income, inside in [
        (0, 2.0, True),
        (0, 5.0, True),
        (0, 1.99, False),
        (0, 5.01, False),
        (10, 6.5, False),
        (10, 7.0, True),
        (10, 10.0, True),
        (10, 10.5, False),
    ]:
        assert bool(model.in_region(np.array([123.0, income]), k)) is inside, (k, income)


def test_macro_horizon_is_20_quarters():
    import importlib

    import gymnasium as gym

    env = gym.make("SDJLS-Macro-v0")
    assert env.unwrapped.horizon == 20
    assert env.spec.max_episode_steps == 20
    assert importlib.import_module("sdjls_gym.systems.macro").HORIZON == 20


# --------------------------------------------------------------------------- validation

nan, inf = float("nan"), float("inf")


def _poke(arr, value):
    """A copy of ``arr`` with its last entry replaced by ``value``."""
    out = np.array(arr, dtype=np.float64)
    out.flat[-1] = value
    return out


# Right-shaped valid values for the paper's sizes (N = 3, n = 2, m = 1, p = 2, r = 2).
_VALID = {
    "A": np.zeros((3, 2, 2)),
    "B": np.ones((2, 1)),
    "E": np.eye(2),
    "W": np.eye(2),
    "P_in": np.eye(3),
    "P_out": np.eye(3),
    "G": np.eye(2),
    "H0": np.zeros(2),
    "H_rate": np.zeros(2),
    "Q": np.eye(2),
    "R": np.eye(1),
    "x0": np.zeros(2),
    "mode0": np.full(3, 1 / 3),
}
_NON_FINITE = [
    pytest.param({name: _poke(value, bad)}, rf"^{name} has a non-finite entry", id=f"{name}-{bad}")
    for name, value in _VALID.items()
    for bad in (nan, inf, -inf)
]

_BAD_MODELS = [
    # shapes and dimensions
    pytest.param({"A": np.zeros((3, 2, 3))}, r"^A has shape \(3, 2, 3\)", id="A-not-square"),
    pytest.param({"A": np.ones((2, 3))}, r"^A has shape \(2, 3\)", id="A-2d-not-square"),
    pytest.param({"A": np.ones(2)}, r"^A has shape \(2,\)", id="A-1d"),
    pytest.param(
        {"A": np.eye(2), "P_in": np.ones(3) / 3}, r"^P_in has shape \(3,\)", id="A-shared-P_in-1d"
    ),
    pytest.param({"B": [[0.0], [1.0], [0.0]]}, r"^B has shape \(3, 1\)", id="B-rows"),
    pytest.param({"B": np.ones((2, 2, 1))}, r"^B has shape \(2, 2, 1\)", id="B-modes"),
    pytest.param({"E": np.eye(3)}, r"^E has shape \(3, 3\)", id="E-rows"),
    pytest.param({"W": np.eye(3)}, r"^W has shape \(3, 3\)", id="W-not-pxp"),
    pytest.param(
        {"E": [[1.0], [0.0]], "W": np.eye(2)}, r"^W has shape \(2, 2\).*\(1, 1\)", id="W-vs-E"
    ),
    pytest.param({"G": [[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]]}, r"^G has shape", id="G-columns"),
    pytest.param({"H0": [-2.0]}, r"^H0 has shape \(1,\)", id="H0-length"),
    pytest.param({"H_rate": [-0.5, 0.5, 0.0]}, r"^H_rate has shape \(3,\)", id="H_rate-length"),
    pytest.param({"P_in": np.eye(2)}, r"^P_in has shape \(2, 2\)", id="P_in-shape"),
    pytest.param({"P_out": np.eye(4)}, r"^P_out has shape \(4, 4\)", id="P_out-shape"),
    pytest.param({"Q": np.eye(3)}, r"^Q has shape \(3, 3\)", id="Q-shape"),
    pytest.param({"Q": np.array([np.eye(2)] * 2)}, r"^Q has shape \(2, 2, 2\)", id="Q-modes"),
    pytest.param({"R": np.eye(2)}, r"^R has shape \(2, 2\)", id="R-shape"),
    pytest.param({"x0": [2.0, 2.0, 2.0]}, r"^x0 has shape \(3,\)", id="x0-length"),
    pytest.param({"A": "abc"}, r"^A = 'abc' is a str", id="A-not-numbers"),
    pytest.param({"A": [[[0, 1], [2]]] * 3}, r"^A = .* could not be read", id="A-ragged"),
    # transition matrices
    pytest.param(
        {"P_in": [[1.2, -0.2, 0.0], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]]},
        r"^P_in\[0, 1\] = -0\.2 is negative",
        id="P_in-negative",
    ),
    pytest.param(
        {"P_out": [[0.67, 0.17, 0.16], [0.30, 0.47, 0.23], [0.26, 0.74, -0.0001]]},
        r"^P_out\[2, 2\] = -0\.0001 is negative",
        id="P_out-negative",
    ),
    pytest.param(
        {"P_in": [[0.6, 0.3, 0.1], [0.25, 0.55, 0.2], [0.35, 0.15, 0.47]]},
        r"^P_in row 2 sums to 0\.97",
        id="P_in-row-sum",
    ),
    pytest.param(
        {"P_out": [[0.67, 0.17, 0.16], [0.30, 0.47, 0.24], [0.26, 0.10, 0.64]]},
        r"^P_out row 1 sums to 1\.01",
        id="P_out-row-sum",
    ),
    pytest.param(
        {"P_out": [[0.67, 0.17, 0.16 + 1e-8], [0.30, 0.47, 0.23], [0.26, 0.10, 0.64]]},
        r"^P_out row 0 sums to",
        id="P_out-row-sum-1e-8",
    ),
    # weights and noise covariance
    pytest.param({"Q": [[1.0, 0.5], [0.0, 1.0]]}, r"^Q\[0\] is not symmetric", id="Q-asym"),
    pytest.param(
        {"Q": [np.eye(2), np.diag([1.0, -1.0]), np.eye(2)]},
        r"^Q\[1\] is not positive semidefinite",
        id="Q-not-psd",
    ),
    pytest.param({"W": [[1.0, 2.0], [2.0, 1.0]]}, r"^W.* is not positive semidefinite", id="W-psd"),
    pytest.param({"W": [[1.0, 0.0], [1.0, 1.0]]}, r"^W.* is not symmetric", id="W-asym"),
    pytest.param(
        {"R": [[[1.0]], [[0.0]], [[1.3]]]}, r"^R\[1\] is not positive definite", id="R-singular"
    ),
    pytest.param(
        {"B": np.eye(2), "R": [[1.0, 0.0], [0.0, -1.0]]},
        r"^R\[0\] is not positive definite",
        id="R-indefinite",
    ),
    pytest.param({"R": [[-1.0]]}, r"^R\[0\] is not positive definite", id="R-negative"),
    # initial mode
    pytest.param({"mode0": 3}, r"^mode0 = 3 is out of range", id="mode0-N"),
    pytest.param({"mode0": -1}, r"^mode0 = -1 is out of range", id="mode0-minus-1"),
    pytest.param(
        {"mode0": np.int64(7)}, r"^mode0 = (np\.int64\()?7\)? is out of range", id="mode0-np-int"
    ),
    pytest.param({"mode0": True}, r"^mode0 = True", id="mode0-bool"),
    pytest.param({"mode0": np.bool_(False)}, r"^mode0 = (np\.)?False", id="mode0-np-bool"),
    pytest.param({"mode0": 1.0}, r"^mode0 = 1\.0 is a float", id="mode0-float"),
    pytest.param(
        {"mode0": [0.5, 0.6, -0.1]}, r"^mode0 = .* is not a probability vector", id="mode0-neg"
    ),
    pytest.param(
        {"mode0": [0.5, 0.6, 0.0]}, r"^mode0 = .* is not a probability vector", id="mode0-sum"
    ),
    pytest.param({"mode0": [0.5, 0.5]}, r"^mode0 has shape \(2,\)", id="mode0-length"),
    # names and region
    pytest.param({"mode_names": ("a", "b")}, r"^mode_names = \('a', 'b'\)", id="names-length"),
    pytest.param({"mode_names": "abc"}, r"^mode_names = 'abc'", id="names-str"),
    pytest.param(
        {"G": np.zeros((0, 2)), "H0": np.zeros(0), "H_rate": np.zeros(0)},
        r"^G has shape \(0, 2\)",
        id="G-empty",
    ),
    pytest.param({"G": [[0.0, -1.0], [0.0, 0.0]]}, r"^G row 1 is all zeros", id="G-zero-row"),
    *_NON_FINITE,
]


@pytest.mark.parametrize(("override", "message"), _BAD_MODELS)
def test_bad_model_raises_value_error_naming_the_field(paper_kwargs, override, message):
    with pytest.raises(ValueError, match=message) as excinfo:
        SDJLSModel(**{**paper_kwargs, **override})
    assert isinstance(excinfo.value, InvalidModelError)


def test_invalid_model_error_is_a_value_error():
    assert issubclass(InvalidModelError, ValueError)


@pytest.mark.parametrize("eps", [1e-10, -1e-10])
def test_row_summing_to_one_within_1e_10_is_accepted(paper_kwargs, eps):
    P_in = np.array(paper_kwargs["P_in"], dtype=np.float64)
    P_in[1, 2] += eps
    assert abs(P_in[1].sum() - 1.0) < 2e-10
    model = SDJLSModel(**{**paper_kwargs, "P_in": P_in, "mode0": [0.2, 0.3, 0.5 + eps]})
    assert model.P_in[1, 2] == P_in[1, 2]


def test_valid_edge_cases_are_accepted(paper_kwargs):
    """W = 0 and Q = 0 are PSD; per-mode matrices given once are shared by every mode."""
    model = SDJLSModel(**{**paper_kwargs, "W": np.zeros((2, 2)), "Q": np.zeros((2, 2))})
    np.testing.assert_array_equal(model.W, np.zeros((2, 2)))
    np.testing.assert_array_equal(model.Q, np.zeros((3, 2, 2)))
    model = SDJLSModel(**{**paper_kwargs, "mode0": np.int64(2)})
    assert model.mode0 == 2
    assert isinstance(model.mode0, int)


# --------------------------------------------------------------------------- (de)serialization


def test_to_dict_from_dict_round_trip(paper_kwargs, other_model):
    for model in (SDJLSModel(**paper_kwargs), other_model):
        data = model.to_dict()
        rebuilt = SDJLSModel.from_dict(data)
        assert rebuilt == model
        assert rebuilt is not model
        np.testing.assert_array_equal(rebuilt.E, model.E)
        assert rebuilt.mode_names == model.mode_names


def test_equality_can_fail(paper_kwargs, other_model):
    model = SDJLSModel(**paper_kwargs)
    assert model != other_model
    assert model != SDJLSModel(**{**paper_kwargs, "x0": [2.0, 2.5]})
    assert model != SDJLSModel(**{**paper_kwargs, "mode_names": ("a", "b", "c")})
    assert model != SDJLSModel(**{**paper_kwargs, "W": 2.0 * np.eye(2)})


@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_save_and_load_round_trip(tmp_path, paper_kwargs, other_model, suffix):
    for i, model in enumerate((SDJLSModel(**paper_kwargs), other_model)):
        path = tmp_path / f"model{i}{suffix}"
        save_model(model, path)
        loaded = load_model(path)
        assert loaded == model
        # and through a plain string path
        assert load_model(str(path)) == model


def test_toml_file_is_real_toml(tmp_path, other_model):
    import tomllib

    path = tmp_path / "m.toml"
    save_model(other_model, path)
    data = tomllib.loads(path.read_text())
    assert data["mode_names"] == ["calm", "stormy"]
    np.testing.assert_array_equal(data["W"], [[0.25]])


def test_toml_round_trip_with_non_bmp_mode_name(tmp_path, paper_kwargs):
    model = SDJLSModel(**{**paper_kwargs, "mode_names": ("normal", "boom \U0001f4c8", "slump")})
    path = tmp_path / "emoji.toml"
    save_model(model, path)
    assert load_model(path) == model


def test_from_dict_unknown_field_is_named(paper_kwargs):
    data = SDJLSModel(**paper_kwargs).to_dict()
    data["A_typo"] = [[1.0]]
    with pytest.raises(InvalidModelError, match=r"unknown model field.*A_typo"):
        SDJLSModel.from_dict(data)


@pytest.mark.parametrize("name", ["A", "G", "x0"])
def test_from_dict_missing_field_is_named(paper_kwargs, name):
    data = SDJLSModel(**paper_kwargs).to_dict()
    del data[name]
    with pytest.raises(InvalidModelError, match=rf"missing model field.*'{name}'"):
        SDJLSModel.from_dict(data)


def test_from_dict_optional_fields_may_be_missing(paper_kwargs):
    data = SDJLSModel(**paper_kwargs).to_dict()
    for name in ("E", "W", "mode0", "mode_names"):
        del data[name]
    model = SDJLSModel.from_dict(data)
    np.testing.assert_array_equal(model.W, np.eye(2))
    assert model.mode0 == 0


@pytest.mark.parametrize(
    ("filename", "content"),
    [
        ("broken.json", b'{"A": [[[0, 1], [2'),
        ("broken.toml", b"A = [[[0, 1], [2\n"),
        pytest.param("latin1.json", b'{"mode_names": ["r\xe9cession"]}'),
        pytest.param("list.json", b"[1, 2, 3]"),
    ],
)
def test_malformed_file_raises_naming_the_file(tmp_path, filename, content):
    path = tmp_path / filename
    path.write_bytes(content)
    with pytest.raises(InvalidModelError, match=re.escape(filename)):
        load_model(path)


def test_file_with_a_bad_value_names_the_field(tmp_path, paper_kwargs):
    data = SDJLSModel(**paper_kwargs).to_dict()
    data["R"] = [[[1.0]], [[-1.2]], [[1.3]]]
    path = tmp_path / "bad_R.json"
    import json

    path.write_text(json.dumps(data))
    # the message names the file first, then the field
    with pytest.raises(InvalidModelError, match=r"bad_R\.json'?: R\[1\] is not positive definite"):
        load_model(path)


# --------------------------------------------------------------------------- immutability

_ARRAY_FIELDS = ["A", "B", "E", "W", "P_in", "P_out", "G", "H0", "H_rate", "Q", "R", "x0"]


def test_model_fields_cannot_be_assigned(paper_kwargs):
    model = SDJLSModel(**paper_kwargs)
    for name in [*_ARRAY_FIELDS, "mode0", "mode_names"]:
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(model, name, getattr(model, name))


@pytest.mark.parametrize("name", _ARRAY_FIELDS)
def test_model_arrays_cannot_be_written(paper_kwargs, name):
    model = SDJLSModel(**paper_kwargs)
    arr = getattr(model, name)
    with pytest.raises(ValueError, match="read-only"):
        arr.flat[0] = 42.0


def test_model_does_not_alias_the_callers_arrays(paper_kwargs):
    A = np.array(paper_kwargs["A"])
    model = SDJLSModel(**{**paper_kwargs, "A": A})
    A[0, 0, 0] = 42.0
    assert model.A[0, 0, 0] == 0.0
    assert model.mode0 == 0


def test_probability_vector_mode0_is_read_only(other_model):
    with pytest.raises(ValueError, match="read-only"):
        other_model.mode0[0] = 1.0


def test_pickled_model_is_equal(other_model, paper_kwargs):
    for model in (SDJLSModel(**paper_kwargs), other_model):
        clone = pickle.loads(pickle.dumps(model))
        assert clone == model
        np.testing.assert_array_equal(clone.W_sqrt @ clone.W_sqrt.T, model.W)


@pytest.mark.parametrize(
    "clone", [lambda m: pickle.loads(pickle.dumps(m)), copy.deepcopy], ids=["pickle", "deepcopy"]
)
def test_copied_model_stays_immutable(paper_kwargs, clone):
    model = clone(SDJLSModel(**paper_kwargs))
    with pytest.raises(ValueError, match="read-only"):
        model.A[0, 0, 0] = 42.0


# --------------------------------------------------------------------------- batched dynamics


def _random_batch(rng, shape):
    """States around the band (some in, some out), modes, times, inputs, noises, uniforms."""
    x = rng.normal([3.0, 4.0], [2.0, 3.0], size=(*shape, 2))
    mode = rng.integers(0, 3, size=shape)
    k = rng.integers(0, 21, size=shape)
    u = rng.normal(0.0, 2.0, size=(*shape, 1))
    w = rng.normal(size=(*shape, 2))
    uniform = rng.random(shape)
    return x, mode, k, u, w, uniform


def test_single_calls_follow_section_2(paper, paper_kwargs):
    """The reference for the batch test, itself checked against the paper's formulas."""
    model = SDJLSModel(**paper_kwargs)
    x, mode, k, u, w, _ = _random_batch(np.random.default_rng(1), (40,))
    for i in range(40):
        m, kk = int(mode[i]), int(k[i])
        values = paper.G @ x[i] - paper.H(kk)
        np.testing.assert_allclose(model.constraint_values(x[i], kk), values, atol=1e-12)
        inside = bool(np.all(values <= 0))
        assert bool(model.in_region(x[i], kk)) is inside
        row = paper.lam[m] if inside else paper.mu[m]
        np.testing.assert_array_equal(model.transition_rows(x[i], m, kk), row)
        expected = paper.A[m] @ x[i] + paper.B @ u[i] + w[i]  # E = I
        np.testing.assert_allclose(model.next_state(x[i], m, u[i], w[i]), expected, atol=1e-12)
        cost = x[i] @ paper.Q[m] @ x[i] + u[i] @ paper.R[m] @ u[i]
        np.testing.assert_allclose(model.stage_cost(x[i], m, u[i]), cost, rtol=1e-12)
    # the test must see both regions
    inside = [bool(model.in_region(x[i], int(k[i]))) for i in range(40)]
    assert any(inside) and not all(inside)


@pytest.mark.parametrize("shape", [(50,), (4, 7)])
def test_batched_dynamics_agree_with_a_loop_of_single_calls(other_model, paper_kwargs, shape):
    rng = np.random.default_rng(7)
    paper_center = lambda k: np.stack([np.zeros(k.shape), 3.5 + 0.5 * k], axis=-1)  # noqa: E731
    other_center = lambda k: np.zeros((*k.shape, 3))  # noqa: E731
    for model, center in ((SDJLSModel(**paper_kwargs), paper_center), (other_model, other_center)):
        N, n, m, p = model.N, model.n, model.m, model.p
        mode = rng.integers(0, N, size=shape)
        k = rng.integers(0, 21, size=shape)
        x = center(k) + rng.normal(0.0, 2.0, size=(*shape, n))
        u = rng.normal(size=(*shape, m))
        w = rng.normal(size=(*shape, p))
        uniform = rng.random(shape)

        x_next, mode_next = model.step(x, mode, u, k, w, uniform)
        batched = {
            "next_state": model.next_state(x, mode, u, w),
            "step_x": x_next,
            "step_mode": mode_next,
            "next_mode": model.next_mode(x, mode, k, uniform),
            "in_region": model.in_region(x, k),
            "transition_rows": model.transition_rows(x, mode, k),
            "constraint_values": model.constraint_values(x, k),
            "stage_cost": model.stage_cost(x, mode, u),
        }
        assert batched["next_state"].shape == (*shape, n)
        assert batched["step_mode"].shape == shape
        assert batched["in_region"].shape == shape
        assert batched["transition_rows"].shape == (*shape, N)
        assert batched["constraint_values"].shape == (*shape, model.r)
        assert np.any(batched["in_region"]) and not np.all(batched["in_region"])

        for idx in np.ndindex(*shape):
            mi, ki = int(mode[idx]), int(k[idx])
            single_x, single_mode = model.step(x[idx], mi, u[idx], ki, w[idx], float(uniform[idx]))
            single = {
                "next_state": model.next_state(x[idx], mi, u[idx], w[idx]),
                "step_x": single_x,
                "step_mode": single_mode,
                "next_mode": model.next_mode(x[idx], mi, ki, float(uniform[idx])),
                "in_region": model.in_region(x[idx], ki),
                "transition_rows": model.transition_rows(x[idx], mi, ki),
                "constraint_values": model.constraint_values(x[idx], ki),
                "stage_cost": model.stage_cost(x[idx], mi, u[idx]),
            }
            for key, value in single.items():
                np.testing.assert_allclose(
                    batched[key][idx], value, rtol=1e-13, atol=1e-13, err_msg=f"{key} at {idx}"
                )


def test_scalar_k_and_mode_broadcast_over_a_batch(paper_kwargs, paper):
    model = SDJLSModel(**paper_kwargs)
    x = np.array([[0.0, 3.0], [0.0, 2.9], [0.0, 6.1]])
    np.testing.assert_array_equal(model.in_region(x, 2), [True, False, False])  # band [3, 6]
    np.testing.assert_array_equal(
        model.transition_rows(x, 1, 2), [paper.lam[1], paper.mu[1], paper.mu[1]]
    )
    np.testing.assert_allclose(
        model.constraint_values(x, 2), x @ paper.G.T - paper.H(2), rtol=0, atol=1e-12
    )


# --------------------------------------------------------------------------- mode sampling

DRAWS = 200_000


def test_next_mode_frequencies_match_the_transition_rows(paper, paper_kwargs):
    """Seeded frequency check of inverse-CDF sampling, without a chi-square test.

    Each of the 18 empirical frequencies (3 modes x 2 regions x 3 next modes, 200000 draws
    each) must lie within 5 standard errors sqrt(p (1 - p) / n) of the paper's probability.
    This is a two-sided 5-sigma bound: under the normal approximation a correct sampler
    fails one check with probability 5.7e-7, so all 18 pass with probability > 99.99%.
    A mis-indexed row or a swapped lambda/mu moves a frequency by >= 0.01, i.e. > 9 errors.
    """
    model = SDJLSModel(**paper_kwargs)
    rng = np.random.default_rng(20240601)
    for x, table in ((np.array([0.0, 3.5]), paper.lam), (np.array([0.0, 9.0]), paper.mu)):
        xs = np.broadcast_to(x, (DRAWS, 2))
        for mode in range(3):
            draws = model.next_mode(xs, mode, 0, rng.random(DRAWS))
            assert draws.shape == (DRAWS,)
            freq = np.bincount(draws, minlength=3) / DRAWS
            p = table[mode]
            se = np.sqrt(p * (1 - p) / DRAWS)
            assert np.all(np.abs(freq - p) <= 5 * se), (mode, freq, p)


def _zero_entry_model():
    P_in = [[0.0, 0.5, 0.5], [0.5, 0.0, 0.5], [0.5, 0.5, 0.0]]
    P_out = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.6, 0.4, 0.0]]
    return SDJLSModel(
        A=np.ones((3, 1, 1)),
        B=[[1.0]],
        P_in=P_in,
        P_out=P_out,
        G=[[1.0]],
        H0=[0.0],
        Q=[[1.0]],
        R=[[1.0]],
        x0=[0.0],
    )


def test_zero_probability_mode_is_never_drawn():
    model = _zero_entry_model()
    rng = np.random.default_rng(3)
    for x in ([-1.0], [1.0]):  # in C1 (P_in) and in C2 (P_out)
        xs = np.broadcast_to(np.array(x), (DRAWS, 1))
        rows = model.P_in if x[0] <= 0 else model.P_out
        for mode in range(3):
            draws = model.next_mode(xs, mode, 0, rng.random(DRAWS))
            counts = np.bincount(draws, minlength=3)
            np.testing.assert_array_equal(counts == 0, rows[mode] == 0, err_msg=f"{x}, {mode}")


_LARGEST_UNIFORM = float(np.nextafter(1.0, 0.0))  # 1 - 2**-53, a possible Generator.random()


@pytest.mark.parametrize(
    ("row", "uniform", "forbidden"),
    [
        pytest.param([0.0, 0.6, 0.4, 0.0], 0.0, 0, id="leading-zero-u=0"),
        pytest.param([0.6, 0.0, 0.4, 0.0], 0.6, 1, id="middle-zero-u=cdf"),
        pytest.param([0.6, 0.3, 0.1, 0.0], _LARGEST_UNIFORM, 3, id="trailing-zero-u=1-2^-53"),
    ],
)
def test_zero_probability_mode_at_the_edges_of_the_uniform(row, uniform, forbidden):
    P = np.array([row] * 4)
    model = SDJLSModel(
        A=np.ones((4, 1, 1)),
        B=[[1.0]],
        P_in=P,
        P_out=P,
        G=[[1.0]],
        H0=[0.0],
        Q=[[1.0]],
        R=[[1.0]],
        x0=[0.0],
    )
    assert int(model.next_mode(np.array([0.0]), 0, 0, uniform)) != forbidden


def test_sample_next_mode_draws_the_transition_rows_with_a_generator():
    """Inside and outside the region, the drawn modes follow ``P_in`` / ``P_out``.

    200,000 draws per (region, mode); each frequency is checked against its row entry with a
    two-sided 99.99% binomial (normal) bound, 18 checks in all. Seeded, so it cannot flake.
    """
    model = sdjls_gym.macro()
    rng = np.random.default_rng(123)
    draws = 200_000
    inside_x, outside_x = np.array([0.0, 3.0]), np.array([0.0, 0.0])  # band at k = 0: [2, 5]
    for x, P in ((inside_x, model.P_in), (outside_x, model.P_out)):
        for mode in range(model.N):
            states = np.broadcast_to(x, (draws, model.n))
            nxt = model.sample_next_mode(states, np.full(draws, mode), 0, rng)
            freq = np.bincount(nxt, minlength=model.N) / draws
            sd = np.sqrt(P[mode] * (1 - P[mode]) / draws)
            assert np.all(np.abs(freq - P[mode]) <= 3.89 * sd), (mode, freq, P[mode])


def test_sample_next_mode_is_next_mode_with_the_generator_uniforms():
    model = sdjls_gym.macro()
    x = np.random.default_rng(0).normal(size=(50, 2)) * 3
    modes, k = np.arange(50) % 3, np.arange(50) % 20
    drawn = model.sample_next_mode(x, modes, k, np.random.default_rng(5))
    replayed = model.next_mode(x, modes, k, np.random.default_rng(5).random(50))
    assert np.array_equal(drawn, replayed)
    with pytest.raises(TypeError, match="expected a numpy.random.Generator"):
        model.sample_next_mode(x, modes, k, 5)


# --------------------------------------------------------------------------- one rule per kind


@pytest.mark.parametrize(
    ("override", "message"),
    [
        pytest.param({"A": "abc"}, r"^A = 'abc' is a str", id="A-str"),
        pytest.param(
            {"Q": [[True, False], [False, True]]}, r"^Q = .* has bool entries", id="Q-bool"
        ),
        pytest.param({"x0": [2.0, None]}, r"^x0 has a missing entry", id="x0-none-entry"),
        pytest.param({"mode0": True}, r"^mode0 = True is a bool", id="mode0-bool"),
        pytest.param({"mode0": "0"}, r"^mode0 = '0' is a str", id="mode0-str"),
        pytest.param(
            {"mode_names": (s for s in ("a", "b", "c"))},
            r"^mode_names = <generator .*> is a generator; expected a list or tuple of 3 str",
            id="mode-names-generator",
        ),
        pytest.param(
            {"mode_names": ("a", 2, "c")}, r"^mode_names\[1\] = 2 is an int", id="names-int"
        ),
        pytest.param({"state_names": {"a", "b"}}, r"^state_names = .* is a set", id="state-set"),
    ],
)
def test_type_errors_are_invalid_model_errors_and_type_errors(paper_kwargs, override, message):
    """A field of the wrong type is an ``InvalidModelTypeError``: a ``TypeError`` and an
    ``InvalidModelError``, so ``except InvalidModelError`` still catches every model error."""
    with pytest.raises(sdjls_gym.InvalidModelTypeError, match=message) as excinfo:
        SDJLSModel(**{**paper_kwargs, **override})
    assert isinstance(excinfo.value, TypeError)
    assert isinstance(excinfo.value, InvalidModelError)
    assert isinstance(excinfo.value, ValueError)


@pytest.mark.parametrize(
    ("mode0", "message"),
    [(2**70, r"^mode0 = 1180591620717411303424 is out of range"), (np.uint64(2**64 - 1), "mode0")],
    ids=["huge-int", "uint64-max"],
)
def test_huge_mode0_is_out_of_range_not_an_overflow(paper_kwargs, mode0, message):
    with pytest.raises(InvalidModelError, match=message) as excinfo:
        SDJLSModel(**{**paper_kwargs, "mode0": mode0})
    assert not isinstance(excinfo.value, TypeError)


# the same matrices times 1e-12, 1 and 1e12 (and 2**-60, exact): same verdict at every scale
_WEIGHTS = {
    "pd": np.array([[2.0, 0.5], [0.5, 1.0]]),
    "psd-singular": np.array([[1.0, 1.0], [1.0, 1.0]]),
    "indefinite": np.array([[1.0, 2.0], [2.0, 1.0]]),
    "asymmetric": np.array([[1.0, 0.5], [0.0, 1.0]]),
}
_SCALES = [1e-12, 2.0**-60, 1.0, 1e12]


@pytest.mark.parametrize("scale", _SCALES)
def test_weight_checks_are_relative_to_the_scale_of_the_matrix(paper_kwargs, scale):
    """``R = 1e-12 I`` is positive definite, as ``I`` is; an indefinite or asymmetric matrix is
    rejected at every scale, a singular PSD one is a valid ``Q`` / ``W`` but not a valid ``R``."""
    B2 = np.array([[1.0, 0.0], [0.0, 1.0]])  # m = 2, so that R is 2 x 2
    base = {**paper_kwargs, "B": B2, "R": np.eye(2)}
    SDJLSModel(**{**base, "R": scale * np.eye(2)})
    SDJLSModel(**{**base, "R": scale * _WEIGHTS["pd"]})
    for field_name in ("Q", "W"):
        SDJLSModel(**{**base, field_name: scale * _WEIGHTS["psd-singular"]})
        SDJLSModel(**{**base, field_name: scale * _WEIGHTS["pd"]})
    with pytest.raises(InvalidModelError, match=r"^R\[0\] is not positive definite"):
        SDJLSModel(**{**base, "R": scale * _WEIGHTS["psd-singular"]})
    for field_name in ("Q", "R", "W"):
        with pytest.raises(InvalidModelError, match=rf"^{field_name}\[0\] is not positive"):
            SDJLSModel(**{**base, field_name: scale * _WEIGHTS["indefinite"]})
        with pytest.raises(InvalidModelError, match=rf"^{field_name}\[0\] is not symmetric"):
            SDJLSModel(**{**base, field_name: scale * _WEIGHTS["asymmetric"]})


def test_nearly_singular_R_is_rejected_at_every_scale(paper_kwargs):
    """diag(1, 1e-13): its smallest eigenvalue is below 1e-12 of its largest entry."""
    B2 = np.eye(2)
    for scale in _SCALES:
        with pytest.raises(InvalidModelError, match=r"^R\[0\] is not positive definite"):
            SDJLSModel(**{**paper_kwargs, "B": B2, "R": scale * np.diag([1.0, 1e-13])})


def _nested(depth, leaf=0.0):
    value = leaf
    for _ in range(depth):
        value = [value]
    return value


@pytest.mark.parametrize("depth", [100, 5000])
def test_deeply_nested_field_names_the_field(paper_kwargs, depth):
    with pytest.raises(InvalidModelError, match=r"^A = .* could not be read"):
        SDJLSModel(**{**paper_kwargs, "A": _nested(depth)})
    with pytest.raises(InvalidModelError, match=r"^mode_names\[0\] = .* is a list"):
        SDJLSModel(**{**paper_kwargs, "mode_names": (_nested(depth, "a"), "b", "c")})


@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_deeply_nested_file_names_the_file_and_the_field(tmp_path, paper_kwargs, suffix):
    """A file nested deeper than Python's parsers can go (a RecursionError inside json/tomllib)
    gives an InvalidModelError naming the file and the field."""
    path = tmp_path / f"deep{suffix}"
    save_model(SDJLSModel(**paper_kwargs), path)
    deep = "[" * 100_000 + "1.0" + "]" * 100_000
    text = path.read_text(encoding="utf-8")
    if suffix == ".json":
        text = text.replace('"H0": [', f'"H0": [{deep}, ', 1)
    else:
        text = text.replace("H0 = [", f"H0 = [{deep}, ", 1)
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InvalidModelError, match=rf"deep\{suffix}'.* levels deep in field 'H0'"):
        load_model(path)


def test_save_model_rejects_what_is_not_a_model(tmp_path, paper_kwargs):
    data = SDJLSModel(**paper_kwargs).to_dict()
    with pytest.raises(TypeError, match=r"^model = \{.* is a dict; expected an SDJLSModel"):
        save_model(data, tmp_path / "m.toml")
    with pytest.raises(TypeError, match=r"^path = 3 is an int"):
        save_model(SDJLSModel(**paper_kwargs), 3)
    with pytest.raises(ValueError, match=r"must end in \.json or \.toml"):
        save_model(SDJLSModel(**paper_kwargs), tmp_path / "m.yaml")
    assert list(tmp_path.iterdir()) == []


_LOCALE_ROUND_TRIP = """
import locale, sys
from pathlib import Path
import sdjls_gym
from sdjls_gym import SDJLSModel, load_model, save_model
assert sys.flags.utf8_mode == 0 and locale.getpreferredencoding(False).lower() != "utf-8", (
    locale.getpreferredencoding(False))
data = sdjls_gym.macro().to_dict()
data["mode_names"] = ["normal", "boom", "r\\u00e9cession"]
data["state_names"] = ["revenu (k-1)", "revenu \\u20ac"]
model = SDJLSModel.from_dict(data)
for suffix in (".toml", ".json"):
    path = Path(sys.argv[1]) / ("model" + suffix)
    save_model(model, path)
    assert load_model(path) == model
    assert "r\\u00e9cession" in path.read_bytes().decode("utf-8")
print("ok")
"""


def test_non_ascii_names_round_trip_under_the_c_locale(tmp_path):
    """``save_model`` writes UTF-8 whatever the locale: under ``LC_ALL=C`` without Python's UTF-8
    mode (the locale encoding is then ASCII) a mode name with an accent is saved and read back."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONIOENCODING": ""}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])
    out = subprocess.run(
        [sys.executable, "-c", _LOCALE_ROUND_TRIP, str(tmp_path)],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


# --------------------------------------------------------------------------- state names


def test_state_names_are_validated_saved_and_compared(tmp_path, paper_kwargs):
    names = ("income (k-1)", "income")
    model = SDJLSModel(**{**paper_kwargs, "state_names": list(names)})
    assert model.state_names == names
    assert SDJLSModel(**paper_kwargs).state_names is None
    assert model.to_dict()["state_names"] == list(names)
    assert SDJLSModel.from_dict(model.to_dict()) == model
    assert model != SDJLSModel(**paper_kwargs)
    assert model != SDJLSModel(**{**paper_kwargs, "state_names": ("a", "b")})
    assert "state_names=('income (k-1)', 'income')" in repr(model)
    for suffix in (".json", ".toml"):
        save_model(model, tmp_path / f"m{suffix}")
        assert load_model(tmp_path / f"m{suffix}").state_names == names
    with pytest.raises(InvalidModelError, match=r"^state_names = .* has 3 items; expected 2"):
        SDJLSModel(**{**paper_kwargs, "state_names": ("a", "b", "c")})
    with pytest.raises(TypeError, match=r"^state_names = 'ab' is a str"):
        SDJLSModel(**{**paper_kwargs, "state_names": "ab"})


def test_macro_preset_names_its_states_after_section_6():
    """x(1) is last quarter's national income (the one-step delayed x(2)), x(2) the income."""
    assert sdjls_gym.macro().state_names == ("income (k-1)", "income")


# --------------------------------------------------------------------------- shared matrices


def test_A_given_once_is_shared_by_every_mode(paper_kwargs, paper):
    """A of shape (n, n) is used in every mode; N is then the size of P_in."""
    A = paper.A[1]
    shared = SDJLSModel(**{**paper_kwargs, "A": A})
    stacked = SDJLSModel(**{**paper_kwargs, "A": np.array([A, A, A])})
    assert shared == stacked
    assert shared.A.shape == (3, 2, 2) and shared.N == 3
    one_mode = SDJLSModel(
        A=[[0.5]], B=[[1.0]], P_in=[[1.0]], P_out=[[1.0]], G=[[1.0]], H0=[1.0], Q=[[1.0]],
        R=[[1.0]], x0=[0.0],
    )  # fmt: skip
    assert one_mode.N == 1 and one_mode.A.shape == (1, 1, 1)


# --------------------------------------------------------------------------- time indices


@pytest.mark.parametrize(
    ("k", "error", "message"),
    [
        (-1, ValueError, r"^k = -1 is out of range; expected an int >= 0"),
        (2**70, ValueError, r"^k = 1180591620717411303424 is too large"),
        (2**2000, ValueError, r"^k = \d+\.\.\. is too large"),
        (np.uint64(2**64 - 1), ValueError, r"is too large"),
        (np.array([0, 2**62]), ValueError, r"^k = 4611686018427387904 is too large"),
        (np.array([3, -2]), ValueError, r"^k = -2 is out of range"),
        (np.array([2**64 - 1], dtype=np.uint64), ValueError, r"is too large"),
        (2.0, TypeError, r"^k = 2\.0 is a float"),
        (True, TypeError, r"^k = True is a bool"),
        (np.array([1.0, 2.0]), TypeError, r"^k = .* has dtype float64"),
    ],
    ids=[
        "negative", "huge", "beyond-float", "uint64-max", "array-huge", "array-negative",
        "uint64-array", "float", "bool", "float-array",
    ],
)  # fmt: skip
def test_time_index_is_checked_exactly(k, error, message):
    """``H``, ``constraint_values``, ``in_region`` and ``constraint_values_one`` check ``k`` on
    the exact integer before any conversion: no OverflowError, no silent wrap or truncation."""
    model = sdjls_gym.macro()
    x = np.array([0.0, 3.0])
    with pytest.raises(error, match=message):
        model.H(k)
    with pytest.raises(error, match=message):
        model.in_region(x, k)
    if np.ndim(k) == 0:
        with pytest.raises(error, match=message):
            model.constraint_values_one(x, k)


def test_valid_time_indices_are_accepted():
    model = sdjls_gym.macro()
    np.testing.assert_array_equal(model.H(np.uint8(4)), model.H(4))
    np.testing.assert_array_equal(model.H([0, 1]), [model.H(0), model.H(1)])
    np.testing.assert_array_equal(model.H(2**53), model.H0 + 2.0**53 * model.H_rate)
    assert model.H(np.zeros(0, dtype=np.int64)).shape == (0, 2)


def test_readme_sections_named_in_the_sources_exist():
    """A pointer such as ``README, "Some section"`` in ``sdjls_gym`` names a real heading."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    headings = set(re.findall(r"^#+ (.+?)\s*$", (root / "README.md").read_text("utf-8"), re.M))
    pointers = []
    for path in sorted((root / "sdjls_gym").rglob("*.py")):
        text = " ".join(line.strip().lstrip("#:").strip() for line in path.read_text().splitlines())
        pointers += [(path.name, name) for name in re.findall(r'README[^".]{0,40}"([^"]+)"', text)]
    assert pointers, "no README pointer found: the test would be vacuous"
    missing = [(file, name) for file, name in pointers if name not in headings]
    assert missing == []
