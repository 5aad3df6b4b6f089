"""Bad input gives a clear error before any work: the catalogue of the model's checks.

Each case is checked by ``conftest.refused`` (and the ``no_solver`` trap).

The model (``SDJLSModel``, its band ``H(k)``) and the model files (``load_model``,
``save_model``). The environments' cases are in ``test_errors_env.py``, the controllers' in
``test_errors_controllers.py``.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import UNSHOWN, refused

from sdjls_gym import (
    InvalidModelError,
    InvalidModelTypeError,
    SDJLSModel,
    load_model,
)
from sdjls_gym import save_model as _save_model
from sdjls_gym.systems.macro import macro

nan, inf = float("nan"), float("inf")
A_DICT = "{'A': array("  # a dict of arrays is shown shortened: its start


# ------------------------------------------------------------------------------------ helpers
def model(ctx, **override):
    """The paper's example (conftest ``paper_kwargs``) with some fields replaced."""
    return SDJLSModel(**{**ctx.kw, **override})


def nested(depth, leaf=0.0):
    value = leaf
    for _ in range(depth):
        value = [value]
    return value


def deep_file(ctx, name):
    """The paper's example saved, with H0 nested 100,000 levels deep (beyond Python's parsers)."""
    path = Path(ctx.tmp_path) / name
    _save_model(SDJLSModel(**ctx.kw), path)
    deep = "[" * 100_000 + "1.0" + "]" * 100_000
    key = '"H0": [' if path.suffix == ".json" else "H0 = ["
    path.write_text(path.read_text().replace(key, f"{key}{deep}, ", 1), encoding="utf-8")
    return load_model(path)


def poke(value, bad):
    """A copy of ``value`` with its last entry replaced by ``bad``."""
    out = np.array(value, dtype=np.float64)
    out.flat[-1] = bad
    return out


def json_file(ctx, name, text):
    path = Path(ctx.tmp_path) / name
    path.write_text(text, encoding="utf-8")
    return load_model(path)


def model_file(ctx, name, **override):
    """Save the paper's example, then replace fields in the text (JSON or TOML)."""
    path = Path(ctx.tmp_path) / name
    _save_model(SDJLSModel(**ctx.kw), path)
    if path.suffix == ".json":
        data = json.loads(path.read_text())
        data.update(override)
        path.write_text(json.dumps(data))  # allow_nan: NaN/Infinity are written as such
    else:
        lines = path.read_text().splitlines()
        for key, text in override.items():
            lines = [f"{key} = {text}" if line.startswith(f"{key} = ") else line for line in lines]
        path.write_text("\n".join(lines) + "\n")
    return load_model(path)


def model_file_without(ctx, name, field):
    path = Path(ctx.tmp_path) / name
    _save_model(SDJLSModel(**ctx.kw), path)
    lines = [line for line in path.read_text().splitlines() if not line.startswith(f"{field} =")]
    path.write_text("\n".join(lines) + "\n")
    return load_model(path)


def case(call, error, name, value, id):
    return pytest.param(call, error, name, value, id=id)


def matrix_case(field, matrix, id):
    """``field`` (a weight or the noise covariance) given as one bad 2 x 2 ``matrix``: refused,
    naming ``field[0]`` and showing the matrix."""
    return case(lambda c: model(c, **{field: matrix}), M, f"{field}[0]", np.array(matrix), id)


M = InvalidModelError
T = InvalidModelTypeError  # both an InvalidModelError and a TypeError
ARRAY_FIELDS = ["A", "B", "E", "W", "P_in", "P_out", "G", "H0", "H_rate", "Q", "R", "x0", "mode0"]

# ------------------------------------------------------------------------------------ the table
CASES = [
    # ---- model: shapes and mismatched dimensions
    case(lambda c: model(c, A=np.zeros((3, 2, 3))), M, "A", (3, 2, 3), "A-not-square"),
    case(lambda c: model(c, A=np.ones((2, 3))), M, "A", (2, 3), "A-2d"),
    case(lambda c: model(c, A=np.eye(2), P_in=[0.5, 0.5]), M, "P_in", (2,), "A-shared-P_in"),
    case(lambda c: model(c, A=[[[0, 1], [2]]] * 3), M, "A", [[[0, 1], [2]]] * 3, "A-ragged"),
    # too deep for repr: shown as "<list object>"
    case(lambda c: model(c, A=nested(5000)), M, "A", UNSHOWN, "A-deep"),
    case(lambda c: model(c, A="abc"), T, "A", "abc", "A-str"),
    case(lambda c: model(c, Q=np.eye(2, dtype=bool)), T, "Q", np.eye(2, dtype=bool), "Q-bool"),
    case(lambda c: model(c, H0=[True, 1.0]), T, "H0", True, "H0-bool-among-numbers"),
    case(lambda c: model(c, B=np.ones((3, 1))), M, "B", (3, 1), "B-rows-vs-n"),
    case(lambda c: model(c, B=np.ones((2, 2, 1))), M, "B", (2, 2, 1), "B-modes-vs-N"),
    case(lambda c: model(c, E=np.eye(3)), M, "E", (3, 3), "E-rows-vs-n"),
    case(lambda c: model(c, E=np.ones((2, 1)), W=np.eye(2)), M, "W", (2, 2), "W-vs-E"),
    case(lambda c: model(c, Q=np.eye(3)), M, "Q", (3, 3), "Q-shape"),
    case(lambda c: model(c, R=np.eye(2)), M, "R", (2, 2), "R-shape-vs-m"),
    case(lambda c: model(c, x0=[2.0, 2.0, 2.0]), M, "x0", (3,), "x0-length"),
    case(lambda c: model(c, P_in=np.eye(2)), M, "P_in", (2, 2), "P_in-shape-vs-N"),
    # ---- model: an empty or inconsistent region G x <= H
    case(
        lambda c: model(c, G=np.zeros((0, 2)), H0=np.zeros(0), H_rate=np.zeros(0)),
        M,
        "G",
        (0, 2),
        "G-empty",
    ),
    case(lambda c: model(c, G=[], H0=[], H_rate=[]), M, "G", (0,), "G-empty-list"),
    case(lambda c: model(c, G=[[0.0, 1.0, 0.0]]), M, "G", (1, 3), "G-columns-vs-n"),
    case(lambda c: model(c, G=[[0.0, -1.0], [0.0, 0.0]]), M, "G", "row 1", "G-0-row"),
    case(lambda c: model(c, H0=[1.0, 2.0, 3.0]), M, "H0", (3,), "H0-length"),
    case(lambda c: model(c, H_rate=[0.5]), M, "H_rate", (1,), "H_rate-length"),
    # ---- model: NaN or inf anywhere (every array field, alternating nan / inf / -inf)
    *[
        case(
            lambda c, f=field, b=bad: model(c, **{f: poke(c.valid[f], b)}),
            M,
            field,
            bad,
            f"{field}-{bad}",
        )
        for field, bad in zip(ARRAY_FIELDS, [nan, inf, -inf] * 5, strict=False)
    ],
    # ---- model: transition matrices
    case(
        lambda c: model(c, P_in=[[1.2, -0.2, 0.0], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]]),
        M,
        "P_in[0, 1]",
        -0.2,
        "P_in-negative",
    ),
    case(
        lambda c: model(c, P_out=[[0.67, 0.17, 0.16], [0.3, 0.47, 0.24], [0.26, 0.1, 0.64]]),
        M,
        "P_out",
        1.01,
        "P_out-row-sum",
    ),
    case(
        lambda c: model(c, P_in=[[0.6, 0.3, 0.1], [0.25, 0.55, 0.2], [0.35, 0.15, 0.47]]),
        M,
        "P_in",
        0.97,
        "P_in-row-sum",
    ),
    # ---- model: weights and noise covariance
    matrix_case("Q", [[1.0, 0.5], [0.0, 1.0]], "Q-asym"),
    case(
        lambda c: model(c, Q=[np.eye(2), np.diag([1.0, -1.0]), np.eye(2)]),
        M,
        "Q[1]",
        np.diag([1.0, -1.0]),
        "Q-not-psd",
    ),
    matrix_case("W", [[1.0, 0.0], [1.0, 1.0]], "W-asym"),
    matrix_case("W", [[1.0, 2.0], [2.0, 1.0]], "W-not-psd"),
    case(
        lambda c: model(c, R=[[[1.0]], [[0.0]], [[1.3]]]), M, "R[1]", np.zeros((1, 1)), "R-singular"
    ),
    case(lambda c: model(c, R=[[-1.0]]), M, "R[0]", -np.ones((1, 1)), "R-negative"),
    # ---- model: initial mode
    case(lambda c: model(c, mode0=3), M, "mode0", 3, "mode0-N"),
    case(lambda c: model(c, mode0=2**70), M, "mode0", 2**70, "mode0-huge"),
    case(
        lambda c: model(c, mode0=np.uint64(2**64 - 1)),
        M,
        "mode0",
        np.uint64(2**64 - 1),
        "mode0-uint64",
    ),
    case(lambda c: model(c, mode0=1.0), T, "mode0", 1.0, "mode0-float"),
    case(lambda c: model(c, mode0=-1), M, "mode0", -1, "mode0-negative"),
    case(lambda c: model(c, G=None), M, "G", None, "G-none"),
    case(lambda c: model(c, H0=[None, 1.0]), M, "H0", None, "H0-null-entry"),
    case(lambda c: model(c, Q=np.eye(2) * (1 + 1j)), T, "Q", np.eye(2) * (1 + 1j), "Q-complex"),
    case(lambda c: model(c, mode0=True), T, "mode0", True, "mode0-bool"),
    case(
        lambda c: model(c, mode0=[0.5, 0.6, -0.1]),
        M,
        "mode0",
        np.array([0.5, 0.6, -0.1]),
        "mode0-vec",
    ),
    case(lambda c: model(c, mode_names=("a", "b")), M, "mode_names", ("a", "b"), "mode-names"),
    case(
        lambda c: model(c, mode_names=(name for name in "abc")),
        T,
        "mode_names",
        "<generator object",
        "mode-names-generator",
    ),
    case(lambda c: model(c, state_names=["income"]), M, "state_names", ["income"], "state-names"),
    case(lambda c: SDJLSModel.from_dict([1, 2]), T, "data", [1, 2], "from-dict-list"),
    case(lambda c: macro().H(2**70), ValueError, "k", 2**70, "H-k-huge"),
    case(
        lambda c: macro().H(np.uint64(2**64 - 1)),
        ValueError,
        "k",
        np.uint64(2**64 - 1),
        "H-k-uint64",
    ),
    case(lambda c: macro().H(2.0), TypeError, "k", 2.0, "H-k-float"),
    # ---- model files: malformed syntax names the file, a malformed field names the field
    case(
        lambda c: json_file(c, "broken.json", '{"A": [[[0, 1], [2'),
        M,
        "model file",
        "broken.json",
        "json-syntax",
    ),
    case(
        lambda c: json_file(c, "broken.toml", "A = [[[0, 1], [2\n"),
        M,
        "model file",
        "broken.toml",
        "toml-syntax",
    ),
    case(
        lambda c: json_file(c, "list.json", "[1, 2, 3]"),
        M,
        "model file",
        "list.json",
        "json-not-a-table",
    ),
    case(lambda c: json_file(c, "model.yaml", "A: 1"), M, "path", "model.yaml", "suffix"),
    case(
        lambda c: model_file(c, "bad_R.json", R=[[[1.0]], [[-1.2]], [[1.3]]]),
        M,
        ("bad_R.json", "R[1]"),
        -np.full((1, 1), 1.2),
        "json-field-R",
    ),
    case(
        lambda c: model_file(c, "nan_A.json", A=[[[nan, 1.0], [-2.5, 3.2]]] * 3),
        M,
        ("nan_A.json", "A"),
        nan,
        "json-field-nan",
    ),
    case(
        lambda c: model_file(c, "typo.json", P_inn=[[1.0]]),
        M,
        "typo.json",
        ["P_inn"],
        "json-unknown-field",
    ),
    case(
        lambda c: model_file(
            c, "rows.toml", P_in="[[0.6, 0.3, 0.2], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]]"
        ),
        M,
        ("rows.toml", "P_in"),
        1.1,
        "toml-field-P_in",
    ),
    case(
        lambda c: model_file(c, "inf_W.toml", W="[[1.0, 0.0], [0.0, inf]]"),
        M,
        ("inf_W.toml", "W"),
        inf,
        "toml-field-inf",
    ),
    case(
        lambda c: model_file(c, "mode0.toml", mode0="5"),
        M,
        ("mode0.toml", "mode0"),
        5,
        "toml-field-mode0",
    ),
    case(
        lambda c: model_file_without(c, "no_G.toml", "G"),
        M,
        "no_G.toml",
        ["G"],
        "toml-missing-field",
    ),
    case(lambda c: deep_file(c, "deep.json"), M, ("deep.json", "H0"), 100001, "json-deep"),
    case(lambda c: deep_file(c, "deep.toml"), M, ("deep.toml", "H0"), 100001, "toml-deep"),
    case(
        lambda c: _save_model(c.kw, Path(c.tmp_path) / "m.toml"),
        TypeError,
        "model",
        A_DICT,
        "save-dict",
    ),
    case(lambda c: _save_model(macro(), 3), TypeError, "path", 3, "save-path"),
]


@pytest.fixture
def ctx(paper_kwargs, tmp_path, no_solver):
    """Inputs of the cases (every solver replaced by a trap: nothing may be solved)."""
    valid = {
        "A": np.zeros((3, 2, 2)), "B": np.ones((2, 1)), "E": np.eye(2), "W": np.eye(2),
        "P_in": np.eye(3), "P_out": np.eye(3), "G": np.eye(2), "H0": np.zeros(2),
        "H_rate": np.zeros(2), "Q": np.eye(2), "R": np.eye(1), "x0": np.zeros(2),
        "mode0": np.full(3, 1 / 3),
    }  # fmt: skip
    return SimpleNamespace(kw=paper_kwargs, tmp_path=tmp_path, valid=valid)


@pytest.mark.parametrize(("call", "error", "name", "value"), CASES)
def test_bad_input_is_refused_naming_the_argument_and_the_value(ctx, call, error, name, value):
    """The error's type, the argument's name and the offending value; no warning on the way,
    raised by a check of this project, before any solver starts."""
    refused(error, name, value, lambda: call(ctx))


def test_the_catalogue_covers_every_field_of_the_model():
    """Every array field of the model has a NaN/inf case in the table."""
    ids = {p.id for p in CASES}
    assert all(ids & {f"{name}-nan", f"{name}-inf", f"{name}--inf"} for name in ARRAY_FIELDS)


# ------------------------------------------------------------------------------------ quoted
def test_the_message_the_style_guide_quotes(paper_kwargs):
    """STYLE.md quotes this message as the example of a good one: kept word for word."""
    P_in = [[0.6, 0.3, 0.1], [0.25, 0.55, 0.2], [0.35, 0.15, 0.47]]
    with pytest.raises(InvalidModelError) as excinfo:
        SDJLSModel(**{**paper_kwargs, "P_in": P_in})
    assert str(excinfo.value).startswith(
        "P_in row 2 sums to 0.97; each row of a transition matrix must sum to 1"
    )
