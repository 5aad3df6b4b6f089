"""SDJLSModel: every field is validated, one rule per kind of argument, time indices exactly.

Each check asserts the exception type, the argument's name and the offending value
(``conftest.raises_naming``), not the sentence around them.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import UNSHOWN, raises_naming

import sdjls_gym
from sdjls_gym import InvalidModelError, SDJLSModel, load_model, save_model

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
    pytest.param({name: _poke(value, bad)}, name, bad, id=f"{name}-{bad}")
    for name, value in _VALID.items()
    for bad in (nan, inf, -inf)
]

_BAD_MODELS = [
    # shapes and dimensions
    pytest.param({"A": np.zeros((3, 2, 3))}, "A", (3, 2, 3), id="A-not-square"),
    pytest.param({"A": np.ones((2, 3))}, "A", (2, 3), id="A-2d-not-square"),
    pytest.param({"A": np.ones(2)}, "A", (2,), id="A-1d"),
    pytest.param({"A": np.eye(2), "P_in": np.ones(3) / 3}, "P_in", (3,), id="A-shared-P_in-1d"),
    pytest.param({"B": [[0.0], [1.0], [0.0]]}, "B", (3, 1), id="B-rows"),
    pytest.param({"B": np.ones((2, 2, 1))}, "B", (2, 2, 1), id="B-modes"),
    pytest.param({"E": np.eye(3)}, "E", (3, 3), id="E-rows"),
    pytest.param({"W": np.eye(3)}, "W", (3, 3), id="W-not-pxp"),
    pytest.param({"E": [[1.0], [0.0]], "W": np.eye(2)}, "W", (2, 2), id="W-vs-E"),
    pytest.param({"G": [[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]]}, "G", (2, 3), id="G-columns"),
    pytest.param({"H0": [-2.0]}, "H0", (1,), id="H0-length"),
    pytest.param({"H_rate": [-0.5, 0.5, 0.0]}, "H_rate", (3,), id="H_rate-length"),
    pytest.param({"P_in": np.eye(2)}, "P_in", (2, 2), id="P_in-shape"),
    pytest.param({"P_out": np.eye(4)}, "P_out", (4, 4), id="P_out-shape"),
    pytest.param({"Q": np.eye(3)}, "Q", (3, 3), id="Q-shape"),
    pytest.param({"Q": np.array([np.eye(2)] * 2)}, "Q", (2, 2, 2), id="Q-modes"),
    pytest.param({"R": np.eye(2)}, "R", (2, 2), id="R-shape"),
    pytest.param({"x0": [2.0, 2.0, 2.0]}, "x0", (3,), id="x0-length"),
    pytest.param({"A": "abc"}, "A", "abc", id="A-not-numbers"),
    pytest.param({"A": [[[0, 1], [2]]] * 3}, "A", [[[0, 1], [2]]] * 3, id="A-ragged"),
    # transition matrices
    pytest.param(
        {"P_in": [[1.2, -0.2, 0.0], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]]},
        "P_in[0, 1]",
        -0.2,
        id="P_in-negative",
    ),
    pytest.param(
        {"P_out": [[0.67, 0.17, 0.16], [0.30, 0.47, 0.23], [0.26, 0.74, -0.0001]]},
        "P_out[2, 2]",
        -0.0001,
        id="P_out-negative",
    ),
    pytest.param(
        {"P_in": [[0.6, 0.3, 0.1], [0.25, 0.55, 0.2], [0.35, 0.15, 0.47]]},
        ("P_in", "row 2"),
        0.97,
        id="P_in-row-sum",
    ),
    pytest.param(
        {"P_out": [[0.67, 0.17, 0.16], [0.30, 0.47, 0.24], [0.26, 0.10, 0.64]]},
        ("P_out", "row 1"),
        1.01,
        id="P_out-row-sum",
    ),
    pytest.param(
        {"P_out": [[0.67, 0.17, 0.16 + 1e-8], [0.30, 0.47, 0.23], [0.26, 0.10, 0.64]]},
        ("P_out", "row 0"),
        1.00000001,
        id="P_out-row-sum-1e-8",
    ),
    # weights and noise covariance
    pytest.param(
        {"Q": [[1.0, 0.5], [0.0, 1.0]]}, "Q[0]", np.array([[1.0, 0.5], [0.0, 1.0]]), id="Q-asym"
    ),
    pytest.param(
        {"Q": [np.eye(2), np.diag([1.0, -1.0]), np.eye(2)]},
        "Q[1]",
        np.diag([1.0, -1.0]),
        id="Q-not-psd",
    ),
    pytest.param(
        {"W": [[1.0, 2.0], [2.0, 1.0]]}, "W[0]", np.array([[1.0, 2.0], [2.0, 1.0]]), id="W-psd"
    ),
    pytest.param(
        {"W": [[1.0, 0.0], [1.0, 1.0]]}, "W[0]", np.array([[1.0, 0.0], [1.0, 1.0]]), id="W-asym"
    ),
    pytest.param({"R": [[[1.0]], [[0.0]], [[1.3]]]}, "R[1]", np.zeros((1, 1)), id="R-singular"),
    pytest.param(
        {"B": np.eye(2), "R": [[1.0, 0.0], [0.0, -1.0]]},
        "R[0]",
        np.diag([1.0, -1.0]),
        id="R-indefinite",
    ),
    pytest.param({"R": [[-1.0]]}, "R[0]", -np.ones((1, 1)), id="R-negative"),
    # initial mode
    pytest.param({"mode0": 3}, "mode0", 3, id="mode0-N"),
    pytest.param({"mode0": -1}, "mode0", -1, id="mode0-minus-1"),
    pytest.param({"mode0": np.int64(7)}, "mode0", np.int64(7), id="mode0-np-int"),
    pytest.param({"mode0": True}, "mode0", True, id="mode0-bool"),
    pytest.param({"mode0": np.bool_(False)}, "mode0", np.bool_(False), id="mode0-np-bool"),
    pytest.param({"mode0": 1.0}, "mode0", 1.0, id="mode0-float"),
    pytest.param({"mode0": [0.5, 0.6, -0.1]}, "mode0", np.array([0.5, 0.6, -0.1]), id="mode0-neg"),
    pytest.param({"mode0": [0.5, 0.6, 0.0]}, "mode0", np.array([0.5, 0.6, 0.0]), id="mode0-sum"),
    pytest.param({"mode0": [0.5, 0.5]}, "mode0", (2,), id="mode0-length"),
    # names and region
    pytest.param({"mode_names": ("a", "b")}, "mode_names", ("a", "b"), id="names-length"),
    pytest.param({"mode_names": "abc"}, "mode_names", "abc", id="names-str"),
    pytest.param(
        {"G": np.zeros((0, 2)), "H0": np.zeros(0), "H_rate": np.zeros(0)},
        "G",
        (0, 2),
        id="G-empty",
    ),
    pytest.param({"G": [[0.0, -1.0], [0.0, 0.0]]}, "G", "row 1", id="G-zero-row"),
    *_NON_FINITE,
]


@pytest.mark.parametrize(("override", "name", "value"), _BAD_MODELS)
def test_bad_model_raises_value_error_naming_the_field(paper_kwargs, override, name, value):
    with raises_naming(InvalidModelError, name, value):  # an InvalidModelError is a ValueError
        SDJLSModel(**{**paper_kwargs, **override})


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


# --------------------------------------------------------------------------- one rule per kind


@pytest.mark.parametrize(
    ("override", "name", "value"),
    [
        pytest.param({"A": "abc"}, "A", "abc", id="A-str"),
        pytest.param(
            {"Q": [[True, False], [False, True]]}, "Q", np.eye(2, dtype=bool), id="Q-bool"
        ),
        pytest.param({"x0": [2.0, None]}, "x0", None, id="x0-none-entry"),
        pytest.param({"mode0": True}, "mode0", True, id="mode0-bool"),
        pytest.param({"mode0": "0"}, "mode0", "0", id="mode0-str"),
        pytest.param(
            {"mode_names": (s for s in ("a", "b", "c"))},
            "mode_names",
            "<generator object",
            id="mode-names-generator",
        ),
        pytest.param({"mode_names": ("a", 2, "c")}, "mode_names[1]", 2, id="names-int"),
        pytest.param({"state_names": {"a", "b"}}, "state_names", "{'", id="state-set"),
    ],
)
def test_type_errors_are_invalid_model_errors_and_type_errors(paper_kwargs, override, name, value):
    """A field of the wrong type is an ``InvalidModelTypeError``: a ``TypeError`` and an
    ``InvalidModelError``, so ``except InvalidModelError`` still catches every model error."""
    with raises_naming(sdjls_gym.InvalidModelTypeError, name, value) as excinfo:
        SDJLSModel(**{**paper_kwargs, **override})
    assert isinstance(excinfo.value, TypeError)
    assert isinstance(excinfo.value, InvalidModelError)
    assert isinstance(excinfo.value, ValueError)


@pytest.mark.parametrize("mode0", [2**70, np.uint64(2**64 - 1)], ids=["huge-int", "uint64-max"])
def test_huge_mode0_is_out_of_range_not_an_overflow(paper_kwargs, mode0):
    with raises_naming(InvalidModelError, "mode0", mode0) as excinfo:
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
    with raises_naming(InvalidModelError, "R[0]", scale * _WEIGHTS["psd-singular"]):
        SDJLSModel(**{**base, "R": scale * _WEIGHTS["psd-singular"]})
    for field_name in ("Q", "R", "W"):
        with raises_naming(InvalidModelError, f"{field_name}[0]", scale * _WEIGHTS["indefinite"]):
            SDJLSModel(**{**base, field_name: scale * _WEIGHTS["indefinite"]})
        with raises_naming(InvalidModelError, f"{field_name}[0]", scale * _WEIGHTS["asymmetric"]):
            SDJLSModel(**{**base, field_name: scale * _WEIGHTS["asymmetric"]})


def test_nearly_singular_R_is_rejected_at_every_scale(paper_kwargs):
    """diag(1, 1e-13): its smallest eigenvalue is below 1e-12 of its largest entry."""
    B2 = np.eye(2)
    for scale in _SCALES:
        with raises_naming(InvalidModelError, "R[0]", scale * np.diag([1.0, 1e-13])):
            SDJLSModel(**{**paper_kwargs, "B": B2, "R": scale * np.diag([1.0, 1e-13])})


def _nested(depth, leaf=0.0):
    value = leaf
    for _ in range(depth):
        value = [value]
    return value


@pytest.mark.parametrize("depth", [100, 5000])
def test_deeply_nested_field_names_the_field(paper_kwargs, depth):
    # too deep for repr at depth 5000: shown as "<list object>"
    shown = depth < 1000
    with raises_naming(InvalidModelError, "A", _nested(depth) if shown else UNSHOWN):
        SDJLSModel(**{**paper_kwargs, "A": _nested(depth)})
    with raises_naming(
        InvalidModelError, "mode_names[0]", _nested(depth, "a") if shown else UNSHOWN
    ):
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
    with raises_naming(InvalidModelError, (f"deep{suffix}", "H0"), 100_001):  # levels deep
        load_model(path)


def test_save_model_rejects_what_is_not_a_model(tmp_path, paper_kwargs):
    data = SDJLSModel(**paper_kwargs).to_dict()
    with raises_naming(TypeError, "model", data):
        save_model(data, tmp_path / "m.toml")
    with raises_naming(TypeError, "path", 3):
        save_model(SDJLSModel(**paper_kwargs), 3)
    with raises_naming(ValueError, "path", "m.yaml"):
        save_model(SDJLSModel(**paper_kwargs), tmp_path / "m.yaml")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- time indices


@pytest.mark.parametrize(
    ("k", "error", "value"),
    [
        (-1, ValueError, -1),
        (2**70, ValueError, 2**70),
        (2**2000, ValueError, 2**2000),
        (np.uint64(2**64 - 1), ValueError, np.uint64(2**64 - 1)),
        (np.array([0, 2**62]), ValueError, 2**62),
        (np.array([3, -2]), ValueError, -2),
        (np.array([2**64 - 1], dtype=np.uint64), ValueError, 2**64 - 1),
        (2.0, TypeError, 2.0),
        (True, TypeError, True),
        (np.array([1.0, 2.0]), TypeError, np.array([1.0, 2.0])),
    ],
    ids=[
        "negative", "huge", "beyond-float", "uint64-max", "array-huge", "array-negative",
        "uint64-array", "float", "bool", "float-array",
    ],
)  # fmt: skip
def test_time_index_is_checked_exactly(k, error, value):
    """``H``, ``constraint_values``, ``in_region`` and ``constraint_values_one`` check ``k`` on
    the exact integer before any conversion: no OverflowError, no silent wrap or truncation."""
    model = sdjls_gym.macro()
    x = np.array([0.0, 3.0])
    with raises_naming(error, "k", value):
        model.H(k)
    with raises_naming(error, "k", value):
        model.in_region(x, k)
    if np.ndim(k) == 0:
        with raises_naming(error, "k", value):
            model.constraint_values_one(x, k)


def test_valid_time_indices_are_accepted():
    model = sdjls_gym.macro()
    np.testing.assert_array_equal(model.H(np.uint8(4)), model.H(4))
    np.testing.assert_array_equal(model.H([0, 1]), [model.H(0), model.H(1)])
    np.testing.assert_array_equal(model.H(2**53), model.H0 + 2.0**53 * model.H_rate)
    assert model.H(np.zeros(0, dtype=np.int64)).shape == (0, 2)
