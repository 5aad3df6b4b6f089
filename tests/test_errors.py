"""Bad input gives a clear error before any work: the one catalogue of the project's checks.

Every public entry point that takes user input appears here with the error it raises and a
fragment of the message (a regular expression): the model, the model files, the environment, the
vector environment, the wrappers, the controllers and the LMI functions. Each case also checks
that

* the exception is raised by this project's own code (the innermost traceback frame is in
  ``sdjls_gym/`` or ``controllers/``), not from deep inside numpy, scipy or cvxpy;
* no solver was started: ``osqp.OSQP.solve`` and ``cvxpy.Problem.solve`` are replaced by a trap
  for the duration of the case.

Several cases also appear in the per-module test files; this table is the single list the
reliability issue asks for. Cases marked ``xfail(strict=True)`` are known bugs (see the reason).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from types import SimpleNamespace

import cvxpy as cp
import gymnasium as gym
import numpy as np
import osqp
import pytest
from gymnasium.error import ResetNeeded

from controllers import (
    LinearFeedbackController,
    MJLSLQRController,
    RecedingHorizonController,
    ScenarioTreeController,
    UnconstrainedRecedingHorizonController,
    check_proposition2,
    row_satisfaction_probability,
    second_moment_spectral_radius,
    synthesize_gains,
    tightened_set_empty,
    tightening,
    verify_mean_square_bound,
)
from sdjls_gym import (
    InvalidModelError,
    InvalidModelTypeError,
    SDJLSEnv,
    SDJLSModel,
    SDJLSVectorEnv,
    load_model,
)
from sdjls_gym import save_model as _save_model
from sdjls_gym.systems.macro import PAPER_K, PAPER_RHC, PAPER_X, PAPER_Y, macro
from sdjls_gym.wrappers import ResidualAction, ViolationPenalty

nan, inf = float("nan"), float("inf")
PSI = PAPER_RHC["Psi"]
LIBRARY_DIRS = ("sdjls_gym", "controllers")


# ------------------------------------------------------------------------------------ helpers
def model(ctx, **override):
    """The paper's example (conftest ``paper_kwargs``) with some fields replaced."""
    return SDJLSModel(**{**ctx.kw, **override})


def rhc(**override):
    kw = {"model": macro(), "K": PAPER_K, **PAPER_RHC}
    kw.update(override)
    return RecedingHorizonController(**kw)


def env_step(action):
    env = gym.make("SDJLS-Macro-v0")
    env.reset(seed=0)
    return env.step(action)


def env_step_after_the_end():
    env = gym.make("SDJLS-v0", model="macro", horizon=1)
    env.reset(seed=0)
    env.step(np.zeros(1, np.float32))
    return env.step(np.zeros(1, np.float32))


def nested(depth, leaf=0.0):
    value = leaf
    for _ in range(depth):
        value = [value]
    return value


def vec_step(actions, num_envs=2):
    envs = SDJLSVectorEnv(num_envs, model="macro")
    envs.reset(seed=0)
    return envs.step(actions)


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


def case(call, error, match, id, bug=None):
    marks = [pytest.mark.xfail(strict=True, reason=f"bug: {bug}")] if bug else []
    return pytest.param(call, error, match, id=id, marks=marks)


M = InvalidModelError
T = InvalidModelTypeError  # both an InvalidModelError and a TypeError
ARRAY_FIELDS = ["A", "B", "E", "W", "P_in", "P_out", "G", "H0", "H_rate", "Q", "R", "x0", "mode0"]

# ------------------------------------------------------------------------------------ the table
CASES = [
    # ---- model: shapes and mismatched dimensions
    case(lambda c: model(c, A=np.zeros((3, 2, 3))), M, r"^A has shape \(3, 2, 3\)", "A-not-square"),
    case(
        lambda c: model(c, A=np.ones((2, 3))),
        M,
        r"^A has shape \(2, 3\); expected \(N, n, n\).* or \(n, n\)",
        "A-2d",
    ),
    case(
        lambda c: model(c, A=np.eye(2), P_in=[0.5, 0.5]),
        M,
        r"^P_in has shape \(2,\); expected \(N, N\).*A of shape \(2, 2\) is shared",
        "A-shared-P_in",
    ),
    case(lambda c: model(c, A=[[[0, 1], [2]]] * 3), M, r"^A = .* could not be read", "A-ragged"),
    case(lambda c: model(c, A=nested(5000)), M, r"^A = .* could not be read", "A-deep"),
    case(lambda c: model(c, A="abc"), T, r"^A = 'abc' is a str", "A-str"),
    case(lambda c: model(c, Q=np.eye(2, dtype=bool)), T, r"^Q = .* has bool entries", "Q-bool"),
    case(
        lambda c: model(c, H0=[True, 1.0]),
        T,
        r"^H0 has an entry True of type bool",
        "H0-bool-among-numbers",
    ),
    case(lambda c: model(c, B=np.ones((3, 1))), M, r"^B has shape \(3, 1\)", "B-rows-vs-n"),
    case(lambda c: model(c, B=np.ones((2, 2, 1))), M, r"^B has shape \(2, 2, 1\)", "B-modes-vs-N"),
    case(lambda c: model(c, E=np.eye(3)), M, r"^E has shape \(3, 3\)", "E-rows-vs-n"),
    case(lambda c: model(c, E=np.ones((2, 1)), W=np.eye(2)), M, r"^W has shape \(2, 2\)", "W-vs-E"),
    case(lambda c: model(c, Q=np.eye(3)), M, r"^Q has shape \(3, 3\)", "Q-shape"),
    case(lambda c: model(c, R=np.eye(2)), M, r"^R has shape \(2, 2\)", "R-shape-vs-m"),
    case(
        lambda c: model(c, x0=[2.0, 2.0, 2.0]),
        M,
        r"^x0 has shape \(3,\); expected \(2,\)",
        "x0-length",
    ),
    case(lambda c: model(c, P_in=np.eye(2)), M, r"^P_in has shape \(2, 2\)", "P_in-shape-vs-N"),
    # ---- model: an empty or inconsistent region G x <= H
    case(
        lambda c: model(c, G=np.zeros((0, 2)), H0=np.zeros(0), H_rate=np.zeros(0)),
        M,
        r"^G has shape \(0, 2\); expected \(r, 2\) with r >= 1",
        "G-empty",
    ),
    case(lambda c: model(c, G=[], H0=[], H_rate=[]), M, r"^G has shape \(0,\)", "G-empty-list"),
    case(lambda c: model(c, G=[[0.0, 1.0, 0.0]]), M, r"^G has shape \(1, 3\)", "G-columns-vs-n"),
    case(lambda c: model(c, G=[[0.0, -1.0], [0.0, 0.0]]), M, r"^G row 1 is all zeros", "G-0-row"),
    case(
        lambda c: model(c, H0=[1.0, 2.0, 3.0]),
        M,
        r"^H0 has shape \(3,\); expected \(2,\)",
        "H0-length",
    ),
    case(
        lambda c: model(c, H_rate=[0.5]),
        M,
        r"^H_rate has shape \(1,\); expected \(2,\)",
        "H_rate-length",
    ),
    # ---- model: NaN or inf anywhere (every array field, alternating nan / inf / -inf)
    *[
        case(
            lambda c, f=field, b=bad: model(c, **{f: poke(c.valid[f], b)}),
            M,
            rf"^{field} has a non-finite entry {str(bad)}",
            f"{field}-{bad}",
        )
        for field, bad in zip(ARRAY_FIELDS, [nan, inf, -inf] * 5, strict=False)
    ],
    # ---- model: transition matrices
    case(
        lambda c: model(c, P_in=[[1.2, -0.2, 0.0], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]]),
        M,
        r"^P_in\[0, 1\] = -0\.2 is negative; transition probabilities must be >= 0",
        "P_in-negative",
    ),
    case(
        lambda c: model(c, P_out=[[0.67, 0.17, 0.16], [0.3, 0.47, 0.24], [0.26, 0.1, 0.64]]),
        M,
        r"^P_out row 1 sums to 1\.01; each row of a transition matrix must sum to 1",
        "P_out-row-sum",
    ),
    case(
        lambda c: model(c, P_in=[[0.6, 0.3, 0.1], [0.25, 0.55, 0.2], [0.35, 0.15, 0.47]]),
        M,
        r"^P_in row 2 sums to 0\.97",
        "P_in-row-sum",
    ),
    # ---- model: weights and noise covariance
    case(lambda c: model(c, Q=[[1.0, 0.5], [0.0, 1.0]]), M, r"^Q\[0\] is not symmetric", "Q-asym"),
    case(
        lambda c: model(c, Q=[np.eye(2), np.diag([1.0, -1.0]), np.eye(2)]),
        M,
        r"^Q\[1\] is not positive semidefinite",
        "Q-not-psd",
    ),
    case(lambda c: model(c, W=[[1.0, 0.0], [1.0, 1.0]]), M, r"^W\[0\] is not symmetric", "W-asym"),
    case(
        lambda c: model(c, W=[[1.0, 2.0], [2.0, 1.0]]),
        M,
        r"^W\[0\] is not positive semi",
        "W-not-psd",
    ),
    case(
        lambda c: model(c, R=[[[1.0]], [[0.0]], [[1.3]]]),
        M,
        r"^R\[1\] is not positive definite",
        "R-singular",
    ),
    case(lambda c: model(c, R=[[-1.0]]), M, r"^R\[0\] is not positive definite", "R-negative"),
    # ---- model: initial mode
    case(
        lambda c: model(c, mode0=3),
        M,
        r"^mode0 = 3 is out of range; expected an int in \[0, 2\] \(modes are numbered from 0",
        "mode0-N",
    ),
    case(
        lambda c: model(c, mode0=2**70), M, r"^mode0 = 1180591620717411303424 is out", "mode0-huge"
    ),
    case(
        lambda c: model(c, mode0=np.uint64(2**64 - 1)), M, r"^mode0 = .* is out of", "mode0-uint64"
    ),
    case(lambda c: model(c, mode0=1.0), T, r"^mode0 = 1\.0 is a float", "mode0-float"),
    case(lambda c: model(c, mode0=-1), M, r"^mode0 = -1 is out of range", "mode0-negative"),
    case(lambda c: model(c, G=None), M, r"^G is missing \(None, or null in a file\)", "G-none"),
    case(
        lambda c: model(c, H0=[None, 1.0]),
        M,
        r"^H0 has a missing entry \(None, or null in a file\) at index \(0,\)",
        "H0-null-entry",
    ),
    case(
        lambda c: model(c, Q=np.eye(2) * (1 + 1j)),
        T,
        r"^Q = .* has complex entries; expected an array of real numbers",
        "Q-complex",
    ),
    case(lambda c: model(c, mode0=True), T, r"^mode0 = True is a bool", "mode0-bool"),
    case(
        lambda c: model(c, mode0=[0.5, 0.6, -0.1]),
        M,
        r"^mode0 = .* is not a probability vector",
        "mode0-vec",
    ),
    case(
        lambda c: model(c, mode_names=("a", "b")),
        M,
        r"^mode_names = \('a', 'b'\) has 2 items; expected 3",
        "mode-names",
    ),
    case(
        lambda c: model(c, mode_names=(name for name in "abc")),
        T,
        r"^mode_names = <generator .*> is a generator; expected a list or tuple of 3 str",
        "mode-names-generator",
    ),
    case(
        lambda c: model(c, state_names=["income"]),
        M,
        r"^state_names = \['income'\] has 1 items; expected 2",
        "state-names",
    ),
    case(
        lambda c: SDJLSModel.from_dict([1, 2]),
        T,
        r"must be a dict/table, got list",
        "from-dict-list",
    ),
    case(lambda c: macro().H(2**70), ValueError, r"^k = 1180591620717411303424 is too", "H-k-huge"),
    case(lambda c: macro().H(np.uint64(2**64 - 1)), ValueError, r"^k = .* is too", "H-k-uint64"),
    case(lambda c: macro().H(2.0), TypeError, r"^k = 2\.0 is a float", "H-k-float"),
    # ---- model files: malformed syntax names the file, a malformed field names the field
    case(
        lambda c: json_file(c, "broken.json", '{"A": [[[0, 1], [2'),
        M,
        r"broken\.json.*not valid UTF-8 JSON",
        "json-syntax",
    ),
    case(
        lambda c: json_file(c, "broken.toml", "A = [[[0, 1], [2\n"),
        M,
        r"broken\.toml.*not valid UTF-8 TOML",
        "toml-syntax",
    ),
    case(
        lambda c: json_file(c, "list.json", "[1, 2, 3]"),
        M,
        r"list\.json.*holds a list",
        "json-not-a-table",
    ),
    case(
        lambda c: json_file(c, "model.yaml", "A: 1"),
        M,
        r"model\.yaml.*must end in \.json or \.toml",
        "suffix",
    ),
    case(
        lambda c: model_file(c, "bad_R.json", R=[[[1.0]], [[-1.2]], [[1.3]]]),
        M,
        r"bad_R\.json'?: R\[1\] is not positive definite",
        "json-field-R",
    ),
    case(
        lambda c: model_file(c, "nan_A.json", A=[[[nan, 1.0], [-2.5, 3.2]]] * 3),
        M,
        r"nan_A\.json'?: A has a non-finite entry nan at index \(0, 0, 0\)",
        "json-field-nan",
    ),
    case(
        lambda c: model_file(c, "typo.json", P_inn=[[1.0]]),
        M,
        r"typo\.json'?: unknown model field\(s\) \['P_inn'\]",
        "json-unknown-field",
    ),
    case(
        lambda c: model_file(
            c, "rows.toml", P_in="[[0.6, 0.3, 0.2], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]]"
        ),
        M,
        r"rows\.toml'?: P_in row 0 sums to 1\.1",
        "toml-field-P_in",
    ),
    case(
        lambda c: model_file(c, "inf_W.toml", W="[[1.0, 0.0], [0.0, inf]]"),
        M,
        r"inf_W\.toml'?: W has a non-finite entry inf",
        "toml-field-inf",
    ),
    case(
        lambda c: model_file(c, "mode0.toml", mode0="5"),
        M,
        r"mode0\.toml'?: mode0 = 5 is out of range",
        "toml-field-mode0",
    ),
    case(
        lambda c: model_file_without(c, "no_G.toml", "G"),
        M,
        r"no_G\.toml'?: missing model field\(s\) \['G'\]",
        "toml-missing-field",
    ),
    case(
        lambda c: deep_file(c, "deep.json"),
        M,
        r"deep\.json'? nests lists or tables 100001 levels deep in field 'H0'",
        "json-deep",
    ),
    case(
        lambda c: deep_file(c, "deep.toml"),
        M,
        r"deep\.toml'? nests lists or tables 100001 levels deep in field 'H0'",
        "toml-deep",
    ),
    case(
        lambda c: _save_model(c.kw, Path(c.tmp_path) / "m.toml"),
        TypeError,
        r"^model = \{.* is a dict; expected an SDJLSModel \(SDJLSModel\.from_dict",
        "save-dict",
    ),
    case(lambda c: _save_model(macro(), 3), TypeError, r"^path = 3 is an int", "save-path"),
    # ---- environment: construction and reset
    case(
        lambda c: SDJLSEnv(3),
        TypeError,
        r"^model = 3 is an int; expected an SDJLSModel, a preset name or a to_dict\(\) dict",
        "env-model",
    ),
    case(
        lambda c: SDJLSEnv(),  # gym.make("SDJLS-v0") re-raises it with the id appended
        TypeError,
        r"^model is missing; pass an SDJLSModel, a preset name \(model='macro'\)",
        "env-no-model",
    ),
    case(
        lambda c: SDJLSEnv("macr0"),
        ValueError,
        r"^model = 'macr0' is not known; expected one of 'macro'",
        "env-preset",
    ),
    case(
        lambda c: SDJLSEnv("macro", horizon=0),
        ValueError,
        r"^horizon = 0 is out of range; expected an int >= 1",
        "env-horizon",
    ),
    case(
        lambda c: SDJLSEnv("macro", horizon=2.0),
        TypeError,
        r"^horizon = 2\.0 is a float; expected an int >= 1",
        "env-horizon-float",
    ),
    case(
        lambda c: SDJLSEnv("macro", horizon=2**70),
        ValueError,
        r"^horizon = 1180591620717411303424 is too large",
        "env-horizon-huge",
    ),
    case(
        lambda c: SDJLSEnv("macro", divergence_bound=True),
        TypeError,
        r"^divergence_bound = True is a bool",
        "env-div-bool",
    ),
    case(
        lambda c: SDJLSEnv("macro", divergence_bound=0.0),
        ValueError,
        r"divergence_bound = 0\.0",
        "env-div-0",
    ),
    case(
        lambda c: SDJLSEnv("macro", divergence_bound=inf),
        ValueError,
        r"divergence_bound = inf",
        "env-div-inf",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=0.0),
        ValueError,
        r"^action_bound = 0\.0 is out of range; expected a finite number > 0",
        "env-bound-0",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=1e300),
        ValueError,
        r"^action_bound = 1e\+300 does not fit in float32; expected a number in \[1\.17549e-38, "
        r"3\.40282e\+38\]",
        "env-bound-float32",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=1e-300),
        ValueError,
        r"^action_bound = 1e-300 does not fit in float32",
        "env-bound-subnormal",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=nan),
        ValueError,
        r"action_bound = nan",
        "env-bound-nan",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound=[1.0, 2.0]),
        ValueError,
        r"action_bound",
        "env-bound-shape",
    ),
    case(
        lambda c: SDJLSEnv("macro", action_bound="big"),
        TypeError,
        r"^action_bound = 'big' is a str",
        "env-bound-string",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"x0": [1.0]}),
        ValueError,
        r"^options\['x0'\] has shape \(1,\); expected \(2,\)",
        "reset-x0",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options=[1, 2]),
        TypeError,
        r"^options = \[1, 2\] is a list; expected a dict with keys among \['mode0', 'x0'\]",
        "reset-options-list",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"mode0": np.uint64(2**64 - 1)}),
        ValueError,
        r"^options\['mode0'\] = .* is out of range; expected an int in \[0, 2\]",
        "reset-mode0-uint64",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"mode0": True}),
        TypeError,
        r"^options\['mode0'\] = True is a bool",
        "reset-mode0-bool",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"x0": [nan, 1.0]}),
        ValueError,
        r"options\['x0'\]",
        "reset-x0-nan",
    ),
    case(
        lambda c: SDJLSEnv("macro").reset(options={"mode0": 3}),
        ValueError,
        r"options\['mode0'\] = 3",
        "reset-mode0",
    ),
    # ---- environment: actions (finite out-of-bounds actions are clipped: see below)
    case(
        lambda c: env_step(np.zeros(2, np.float32)),
        ValueError,
        r"action has shape \(2,\); expected \(1,\)",
        "step-shape",
    ),
    case(
        lambda c: env_step(np.zeros((1, 1), np.float32)),
        ValueError,
        r"action has shape \(1, 1\)",
        "step-2d",
    ),
    case(
        lambda c: env_step(np.zeros(0, np.float32)),
        ValueError,
        r"action has shape \(0,\)",
        "step-empty",
    ),
    case(
        lambda c: env_step(np.array([nan], np.float32)),
        ValueError,
        r"action = \[nan\] contains NaN or inf",
        "step-nan",
    ),
    case(
        lambda c: env_step(np.array([inf])),
        ValueError,
        r"action = \[inf\] contains NaN or inf",
        "step-inf",
    ),
    case(
        lambda c: env_step(np.array([-inf])),
        ValueError,
        r"action = \[-inf\] contains NaN or inf",
        "step-minus-inf",
    ),
    case(
        lambda c: env_step("a"),
        ValueError,  # NotANumberError: a ValueError and a TypeError
        r"^action = 'a' is a str; expected an array of numbers \(the input u_k, 1 finite number",
        "step-string",
    ),
    case(
        lambda c: env_step(None),
        TypeError,  # NotANumberError: a ValueError and a TypeError
        r"^action = None is a NoneType; expected an array of numbers \(the input u_k",
        "step-none",
    ),
    case(
        lambda c: env_step_after_the_end(),
        ResetNeeded,
        r"^step\(\) called after the episode ended \(truncated at k = 1 = horizon\); call reset",
        "step-after-end",
    ),
    # ---- vector environment
    case(
        lambda c: SDJLSVectorEnv(0, model="macro"),
        ValueError,
        r"^num_envs = 0 is out of range; expected an int >= 1",
        "vec-num-envs",
    ),
    case(
        lambda c: SDJLSVectorEnv(2, model="macro", max_episode_steps=0),
        ValueError,
        r"^max_episode_steps = 0 is out of range",
        "vec-max-steps",
    ),
    case(
        lambda c: SDJLSVectorEnv(2, model="macro", horizon=2.0),
        TypeError,
        r"^horizon = 2\.0 is a float",
        "vec-horizon-float",
    ),
    case(
        lambda c: SDJLSVectorEnv(2),
        TypeError,
        r"^model is missing; pass an SDJLSModel",
        "vec-no-model",
    ),
    case(
        lambda c: vec_step(np.zeros((3, 1), np.float32)),
        ValueError,
        r"actions have shape \(3, 1\); expected \(2, 1\)",
        "vec-shape",
    ),
    case(
        lambda c: vec_step(np.array([[0.0], [nan]])),
        ValueError,
        r"actions contain NaN or inf",
        "vec-nan",
    ),
    case(
        lambda c: vec_step(np.array([[inf], [0.0]])),
        ValueError,
        r"actions contain NaN or inf",
        "vec-inf",
    ),
    case(
        lambda c: vec_step([["a"], ["b"]]),
        ValueError,
        r"actions",
        "vec-string",
    ),
    case(
        lambda c: SDJLSVectorEnv(2, model="macro").reset(options={"mode0": 5}),
        ValueError,
        r"^options\['mode0'\] = 5 is out of range",
        "vec-reset",
    ),
    # ---- wrappers
    case(
        lambda c: ViolationPenalty(gym.make("SDJLS-Macro-v0"), -1.0),
        ValueError,
        r"beta = -1\.0",
        "penalty-beta",
    ),
    case(
        lambda c: ViolationPenalty(gym.make("SDJLS-Macro-v0"), "high"),
        TypeError,
        r"^beta = 'high' is a str",
        "penalty-beta-string",
    ),
    case(
        lambda c: ViolationPenalty(gym.make("SDJLS-Macro-v0"), 10**400),
        ValueError,
        r"^beta = 1000.* is not finite; expected a finite number >= 0",
        "penalty-beta-huge-int",
    ),
    case(
        lambda c: ViolationPenalty(gym.make("SDJLS-Macro-v0"), True),
        TypeError,
        r"^beta = True is a bool",
        "penalty-beta-bool",
    ),
    case(
        lambda c: ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K[0]),
        ValueError,
        r"K has shape \(1, 2\); expected \(3, 1, 2\)",
        "residual-K",
    ),
    case(
        lambda c: ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K, nu_bound=0.0),
        ValueError,
        r"nu_bound = 0\.0",
        "residual-nu-0",
    ),
    case(
        lambda c: ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K, nu_bound="big"),
        TypeError,
        r"^nu_bound = 'big' is a str",
        "residual-nu-string",
    ),
    case(
        lambda c: ResidualAction(gym.make("SDJLS-Macro-v0"), PAPER_K, nu_bound=1e39),
        ValueError,
        r"^nu_bound = 1e\+39 does not fit in float32",
        "residual-nu-float32",
    ),
    case(
        lambda c: ResidualAction(
            gym.wrappers.RescaleAction(gym.make("SDJLS-Macro-v0"), np.float32(-1), np.float32(1)),
            PAPER_K,
        ),
        ValueError,
        r"^ResidualAction must wrap the SDJLS environment directly: RescaleAction",
        "residual-over-rescale",
    ),
    # ---- receding-horizon controller: construction
    case(
        lambda c: rhc(model="macro"),
        TypeError,
        r"model = 'macro' is a str; expected an sdjls_gym\.SDJLSModel",
        "rhc-model",
    ),
    case(
        lambda c: rhc(xi=0.0),
        ValueError,
        r"xi = 0\.0 is out of range; expected a finite number in \(0, 1\)",
        "xi-0",
    ),
    case(
        lambda c: rhc(xi=1.0),
        ValueError,
        r"xi = 1\.0 is out of range; expected a finite number in \(0, 1\)",
        "xi-1",
    ),
    case(lambda c: rhc(xi=-0.1), ValueError, r"xi = -0\.1 is out of range", "xi-negative"),
    case(lambda c: rhc(xi=1.5), ValueError, r"xi = 1\.5 is out of range", "xi-above-1"),
    case(lambda c: rhc(xi=nan), ValueError, r"xi = nan is not finite", "xi-nan"),
    case(lambda c: rhc(xi=True), TypeError, r"xi = True is a bool", "xi-bool"),
    case(
        lambda c: rhc().act([True, 1.0], 0, 0),
        TypeError,
        r"^x has an entry True of type bool",
        "act-x-bool-among-numbers",
    ),
    case(lambda c: rhc(xi="0.85"), TypeError, r"xi = '0\.85' is a str", "xi-str"),
    case(lambda c: rhc(alpha="1000"), TypeError, r"alpha = '1000' is a str", "alpha-str"),
    case(lambda c: rhc(alpha=True), TypeError, r"alpha = True is a bool", "alpha-bool"),
    case(
        lambda c: rhc(alpha=1e13),
        ValueError,
        r"alpha = 10000000000000\.0 is out of range; expected a finite number in \(0, 1e\+12\]",
        "alpha-above-limit",
    ),
    case(
        lambda c: rhc(nu_bound=1e13),
        ValueError,
        r"nu_bound = 10000000000000\.0 is out of range; expected a finite number in \(0, 1e\+12\]",
        "nu-bound-above-limit",
    ),
    case(
        lambda c: rhc(Psi=1e200 * PSI),
        ValueError,
        r"has an entry of magnitude .* every entry must be at most 1e\+100",
        "Psi-huge",
    ),
    case(
        lambda c: RecedingHorizonController(
            SDJLSModel(**{**c.kw, "R": 1e120 * np.ones((1, 1))}), PAPER_K, **PAPER_RHC
        ),
        ValueError,
        r"model\.R up to 1e\+120",
        "R-huge",
    ),
    case(
        lambda c: rhc(horizon=2.0),
        TypeError,
        r"horizon = 2\.0 is a float; expected an int >= 1",
        "rhc-horizon-float",
    ),
    case(
        lambda c: LinearFeedbackController(macro(), PAPER_K, horizon=2.0),
        TypeError,
        r"horizon = 2\.0 is a float; expected an int >= 1",
        "linear-horizon-float",
    ),
    case(lambda c: rhc(alpha=0.0), ValueError, r"alpha = 0\.0 is out of range; .*\(0, ", "alpha-0"),
    case(lambda c: rhc(alpha=-5.0), ValueError, r"alpha = -5\.0 is out of range", "alpha-negative"),
    case(lambda c: rhc(alpha=inf), ValueError, r"alpha = inf is not finite", "alpha-inf"),
    case(lambda c: rhc(nu_bound=0.0), ValueError, r"nu_bound = 0\.0 is out of range", "nu-bound-0"),
    case(
        lambda c: rhc(nu_bound=-1.0),
        ValueError,
        r"nu_bound = -1\.0 is out of range",
        "nu-bound-neg",
    ),
    case(
        lambda c: rhc(Psi=np.array([np.eye(2), -np.eye(2), np.eye(2)])),
        ValueError,
        r"Psi\[1\] is not positive definite",
        "Psi-neg",
    ),
    case(
        lambda c: rhc(Psi=np.zeros((3, 2, 2))),
        ValueError,
        r"Psi\[0\] = .* is not symmetric positive definite",
        "Psi-0",
    ),
    case(
        lambda c: rhc(Psi=np.array([[[1.0, 0.5], [0.0, 1.0]]] * 3)),
        ValueError,
        r"Psi\[0\] = .* is not symmetric positive definite",
        "Psi-asym",
    ),
    case(lambda c: rhc(Psi=poke(PSI, nan)), ValueError, r"Psi has a non-finite entry", "Psi-nan"),
    case(
        lambda c: rhc(Psi=np.eye(2)),
        ValueError,
        r"Psi has shape \(2, 2\); expected \(3, 2, 2\)",
        "Psi-shape",
    ),
    case(
        lambda c: rhc(K=PAPER_K[:, :, :1]),
        ValueError,
        r"K has shape \(3, 1, 1\); expected \(3, 1, 2\)",
        "K-shape",
    ),
    case(
        lambda c: rhc(K=PAPER_K[0]),
        ValueError,
        r"K has shape \(1, 2\); expected \(3, 1, 2\)",
        "K-no-modes",
    ),
    case(
        lambda c: rhc(K=poke(PAPER_K, inf)),
        ValueError,
        r"K has a non-finite entry inf at index \(2, 0, 1\)",
        "K-inf",
    ),
    case(
        lambda c: rhc(constraint="chance"),
        ValueError,
        r"constraint = 'chance' is not known; expected one of 'individual'",
        "constraint",
    ),
    case(lambda c: rhc(solver="gurobi"), ValueError, r"solver = 'gurobi' is not known", "solver"),
    case(lambda c: rhc(nu_set="sphere"), ValueError, r"nu_set = 'sphere' is not known", "nu-set"),
    case(
        lambda c: rhc(osqp_settings={"max_iterations": 5}),
        ValueError,
        r"osqp_settings = .* were rejected by OSQP",
        "osqp-name",
    ),
    case(lambda c: rhc(osqp_settings=3), TypeError, r"osqp_settings = 3 is an int", "osqp-type"),
    case(
        lambda c: rhc(cvxpy_fallback="yes"),
        TypeError,
        r"cvxpy_fallback = 'yes' is a str; expected True or False",
        "fallback",
    ),
    case(
        lambda c: UnconstrainedRecedingHorizonController(macro(), PAPER_K, Psi=PSI, alpha=0.0),
        ValueError,
        r"alpha = 0\.0 is out of range",
        "unconstrained-alpha",
    ),
    # ---- receding-horizon controller: act and act_batch
    case(
        lambda c: rhc().act([1.0, 2.0, 3.0], 0, 0),
        ValueError,
        r"x has shape \(3,\); expected \(2,\)",
        "act-x-shape",
    ),
    case(
        lambda c: rhc().act([1.0, nan], 0, 0),
        ValueError,
        r"x has a non-finite entry nan at index \(1,\)",
        "act-x-nan",
    ),
    case(
        lambda c: rhc().act([1.0, 2.0], 3, 0),
        ValueError,
        r"mode = 3 is out of range; expected an int in \[0, 2\]",
        "act-mode",
    ),
    case(
        lambda c: rhc().act([1.0, 2.0], 1.0, 0),
        TypeError,
        r"mode = 1\.0 is a float; expected an int",
        "act-mode-float",
    ),
    case(lambda c: rhc().act([1.0, 2.0], 0, -1), ValueError, r"k = -1 is out of range", "act-k"),
    case(
        lambda c: rhc().act([1.0, 2.0], 0, 2**70),
        ValueError,
        r"k = 1180591620717411303424 is out of range; expected an int in \[0, 9007199254740991\] "
        r"\(time index, at most 2\*\*53 - 1: the controller reads the band H up to k \+ 1\)",
        "act-k-huge",
    ),
    case(
        lambda c: rhc().act([1.0, 2.0], 0, np.uint64(2**64 - 1)),
        ValueError,
        r"k = np\.uint64\(18446744073709551615\) is out of range; .*at most 2\*\*53 - 1",
        "act-k-uint64-max",
    ),
    case(
        lambda c: rhc().act_batch(
            np.zeros((2, 2)), np.zeros(2, int), np.full(2, 2**64 - 1, np.uint64)
        ),
        ValueError,
        r"k = np\.uint64\(18446744073709551615\) is out of range",
        "batch-k-uint64-max",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((2, 2)), np.zeros(2, int), 10**30),
        ValueError,
        r"^k = 1000000000000000000000000000000 is out of range; expected an int in \[0, ",
        "batch-k-python-huge",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((2, 2)), np.zeros(2, int), [10**30, 1]),
        ValueError,
        r"^k = 1000000000000000000000000000000 is out of range",
        "batch-k-python-huge-list",
    ),
    case(
        lambda c: rhc().act([1.0, 2.0], 0, 2**53),
        ValueError,
        r"^k = 9007199254740992 is out of range; expected an int in \[0, 9007199254740991\]",
        "act-k-2-53-needs-k-plus-1",
    ),
    case(
        lambda c: ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=3).act(
            [1.0, 2.0], 0, 2**53 - 2
        ),
        ValueError,
        r"^k = 9007199254740990 is out of range; expected an int in \[0, 9007199254740989\] "
        r"\(time index, at most 2\*\*53 - 3: the controller reads the band H up to k \+ 3\)",
        "tree-k-beyond-2-53-minus-steps",
    ),
    case(
        lambda c: ScenarioTreeController(macro(), PAPER_K, **PAPER_RHC, steps=2.5),
        ValueError,  # NotAnIntError: a ValueError and a TypeError
        r"^steps = 2\.5 is a float; expected an int >= 1",
        "tree-steps-non-integer",
    ),
    case(
        lambda c: rhc().act(np.array([1e101, 0.0]), 0, 0),
        ValueError,
        r"^x = \[1\.e\+101, 0\.e\+000\] has an entry of magnitude above 1e\+100",
        "act-huge-state",
    ),
    case(
        lambda c: rhc().act_batch(np.array([[0.0, 1.0], [0.0, -2e300]]), np.zeros(2, int), 0),
        ValueError,
        r"^x\[1\] = .* has an entry of magnitude above 1e\+100",
        "act-batch-huge-state",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 3)), np.zeros(4, int), 0),
        ValueError,
        r"x has shape \(4, 3\); expected \(B, 2\)",
        "batch-x-shape",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 2)), np.zeros(3, int), 0),
        ValueError,
        r"mode has shape \(3,\); expected \(4,\)",
        "batch-mode-shape",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 2)), np.full(4, 3), 0),
        ValueError,
        r"mode = np\.int64\(3\) is out of range; expected ints in \[0, 2\]",
        "batch-mode",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 2)), np.zeros(4), 0),
        TypeError,
        r"mode has dtype float64; expected integers",
        "batch-mode-float",
    ),
    case(
        lambda c: rhc().act_batch(np.full((4, 2), inf), np.zeros(4, int), 0),
        ValueError,
        r"x has a non-finite entry",
        "batch-x-inf",
    ),
    case(
        lambda c: rhc().act_batch(np.zeros((4, 2)), np.zeros(4, int), -1),
        ValueError,
        r"k = -1 is out of range",
        "batch-k",
    ),
    # ---- chance constraints
    case(
        lambda c: tightening(macro(), 0.0),
        ValueError,
        r"xi = 0\.0 is out of range",
        "tightening-xi-0",
    ),
    case(
        lambda c: tightening(macro(), 1),
        ValueError,
        r"xi = 1 is out of range",
        "tightening-xi-1",
    ),
    case(
        lambda c: tightening(macro(), 0.9, "both"),
        ValueError,
        r"constraint = 'both'",
        "tightening-kind",
    ),
    case(
        lambda c: tightening(c.kw, 0.9),
        TypeError,
        r"model = \{.* is a dict; expected an sdjls_gym\.SDJLSModel",
        "tightening-model",
    ),
    case(
        lambda c: tightened_set_empty(macro(), 1.5, 1),
        ValueError,
        r"xi = 1\.5 is out of range",
        "empty-set-xi",
    ),
    case(
        lambda c: tightened_set_empty(macro(), 0.9, -2),
        ValueError,
        r"k_next = -2 is out of range; expected an int >= 0",
        "empty-set-k-negative",
    ),
    case(
        lambda c: tightened_set_empty(macro(), 0.9, 2.0),
        TypeError,
        r"k_next = 2\.0 is a float; expected an int >= 0",
        "empty-set-k-float",
    ),
    case(
        lambda c: tightened_set_empty(macro(), 0.9, 1, "all"),
        ValueError,
        r"constraint = 'all'",
        "empty-set-kind",
    ),
    case(
        lambda c: tightened_set_empty(c.kw, 0.9, 1),
        TypeError,
        r"model = \{.* is a dict; expected an sdjls_gym\.SDJLSModel",
        "empty-set-model",
    ),
    case(
        lambda c: row_satisfaction_probability(macro(), np.zeros(3), 0, 1),
        ValueError,
        r"mean_next has shape \(3,\)",
        "probability-mean",
    ),
    case(
        lambda c: row_satisfaction_probability(macro(), np.zeros(2), 3, 1),
        ValueError,
        r"mode = .* in \[0, 3\)",
        "probability-mode",
    ),
    # ---- baselines
    case(
        lambda c: LinearFeedbackController(macro(), np.zeros((3, 2))),
        ValueError,
        r"K has shape \(3, 2\); expected \(3, 1, 2\)",
        "linear-K",
    ),
    case(
        lambda c: MJLSLQRController(macro(), transition=0.5 * np.eye(3)),
        ValueError,
        r"transition row 0 sums to 0\.5",
        "lqr-P",
    ),
    # ---- LMI synthesis and certificate
    case(
        lambda c: synthesize_gains(c.kw),
        TypeError,
        r"model = \{.* is a dict; expected an sdjls_gym\.SDJLSModel",
        "synth-model",
    ),
    case(
        lambda c: synthesize_gains(macro(), eps=0.0),
        ValueError,
        r"eps = 0\.0 is out of range; expected a finite number > 0",
        "synth-eps-0",
    ),
    case(
        lambda c: synthesize_gains(macro(), eps=-1e-6), ValueError, r"eps = -1e-06", "synth-eps-neg"
    ),
    case(
        lambda c: synthesize_gains(macro(), objective="fastest"),
        ValueError,
        r"objective = 'fastest'; expected one of",
        "synth-objective",
    ),
    case(
        lambda c: synthesize_gains(macro(), solver="NOPE"),
        ValueError,
        r"solver = 'NOPE' is not an installed cvxpy solver",
        "synth-solver",
    ),
    case(
        lambda c: verify_mean_square_bound(macro(), PAPER_K[0]),
        ValueError,
        r"K has shape \(1, 2\); expected \(3, 1, 2\)",
        "verify-K",
    ),
    case(
        lambda c: verify_mean_square_bound(macro(), PAPER_K, nu_bound=-1.0),
        ValueError,
        r"nu_bound = -1\.0",
        "verify-nu-bound",
    ),
    case(
        lambda c: verify_mean_square_bound(macro(), PAPER_K, kappa=0.0),
        ValueError,
        r"kappa = 0\.0",
        "verify-kappa",
    ),
    case(
        lambda c: second_moment_spectral_radius(macro(), PAPER_K[:, :, :1]),
        ValueError,
        r"K has shape \(3, 1, 1\)",
        "radius-K",
    ),
    case(
        lambda c: check_proposition2(macro(), PAPER_X[:2], PAPER_Y),
        ValueError,
        r"X has shape \(2, 2, 2\); expected \(3, 2, 2\)",
        "prop2-X",
    ),
]


class SolverCalled(BaseException):
    """Raised by the trap set on the solvers; a BaseException, which no ``except Exception``
    in the library can hide."""


@pytest.fixture
def ctx(paper_kwargs, tmp_path, monkeypatch):
    """Inputs of the cases, with every solver replaced by a trap (nothing may be solved)."""

    def trap(*args, **kwargs):
        raise SolverCalled("a solver was started before the bad input was rejected")

    monkeypatch.setattr(osqp.OSQP, "solve", trap)
    monkeypatch.setattr(cp.Problem, "solve", trap)
    valid = {
        "A": np.zeros((3, 2, 2)), "B": np.ones((2, 1)), "E": np.eye(2), "W": np.eye(2),
        "P_in": np.eye(3), "P_out": np.eye(3), "G": np.eye(2), "H0": np.zeros(2),
        "H_rate": np.zeros(2), "Q": np.eye(2), "R": np.eye(1), "x0": np.zeros(2),
        "mode0": np.full(3, 1 / 3),
    }  # fmt: skip
    return SimpleNamespace(kw=paper_kwargs, tmp_path=tmp_path, valid=valid)


def _in_library(path: str) -> bool:
    parts = Path(path).parts
    return "site-packages" not in parts and any(d in parts for d in LIBRARY_DIRS)


@pytest.mark.parametrize(("call", "error", "match"), CASES)
def test_bad_input_gives_a_clear_error_before_any_work(ctx, call, error, match):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning on the way to the error either
        with pytest.raises(error, match=match) as excinfo:
            call(ctx)
    innermost = excinfo.traceback[-1]
    assert _in_library(str(innermost.path)), (
        f"{type(excinfo.value).__name__} raised from {innermost.path}:{innermost.lineno + 1}, "
        "not from a check in sdjls_gym/ or controllers/"
    )


def test_the_catalogue_covers_every_field_of_the_model():
    """Every array field of the model has a NaN/inf case in the table."""
    ids = {p.id for p in CASES}
    assert all(ids & {f"{name}-nan", f"{name}-inf", f"{name}--inf"} for name in ARRAY_FIELDS)


# ------------------------------------------------------------------------------------ no work
def _env_snapshot(env):
    base = env.unwrapped
    return (base.state, base.mode, base.k, base.np_random.bit_generator.state)


BAD_ACTIONS = [
    pytest.param(np.array([nan]), id="nan"),
    pytest.param(np.array([inf]), id="inf"),
    pytest.param(np.zeros(2), id="shape"),
    pytest.param("a", id="string"),
    # not numbers, never read as 1.0 (NotANumberError: both a ValueError and a TypeError)
    pytest.param(["1"], id="numeric-string"),
    pytest.param([True], id="bool-list"),
    pytest.param(np.array([True]), id="bool-array"),
    pytest.param(None, id="none"),
]


@pytest.mark.parametrize("action", BAD_ACTIONS)
def test_rejected_action_leaves_the_env_untouched(action):
    """A rejected action neither advances time nor consumes randomness: the episode continues
    exactly as if the bad call had not been made."""
    env, ref = gym.make("SDJLS-Macro-v0"), gym.make("SDJLS-Macro-v0")
    env.reset(seed=11)
    ref.reset(seed=11)
    env.step(np.array([3.0], np.float32))
    ref.step(np.array([3.0], np.float32))
    before = _env_snapshot(env)
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    after = _env_snapshot(env)
    np.testing.assert_array_equal(after[0], before[0])
    assert after[1:] == before[1:]
    out, expected = env.step(np.array([4.0], np.float32)), ref.step(np.array([4.0], np.float32))
    np.testing.assert_array_equal(out[0], expected[0])
    assert out[1:4] == expected[1:4]
    np.testing.assert_array_equal(out[4]["state"], expected[4]["state"])


@pytest.mark.parametrize(
    "actions",
    [
        np.array([[0.0], [nan]]),
        np.array([[inf], [0.0]]),
        np.zeros((3, 1)),
        np.zeros((2, 2)),
        [["1"], ["2"]],
        np.array([[True], [False]]),
    ],
    ids=["nan", "inf", "batch-size", "m", "numeric-strings", "bools"],
)
def test_rejected_actions_leave_the_vector_env_untouched(actions):
    envs, ref = SDJLSVectorEnv(2, model="macro"), SDJLSVectorEnv(2, model="macro")
    envs.reset(seed=5)
    ref.reset(seed=5)
    rng_state = envs.np_random.bit_generator.state
    with pytest.raises(ValueError, match="actions"):
        envs.step(actions)
    assert envs.np_random.bit_generator.state == rng_state
    good = np.array([[1.0], [-2.0]])
    a, b = envs.step(good), ref.step(good)
    for x, y in zip(a[:4], b[:4], strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a[4]["state"], b[4]["state"])
    np.testing.assert_array_equal(a[4]["k"], [1, 1])


# ------------------------------------------------------------------------------------ clipping
EXTREME = [1e300, -1e300, float(np.finfo(np.float32).max), -float(np.finfo(np.float64).max)]


def test_out_of_bounds_finite_actions_are_clipped_and_documented():
    """Finite actions outside the Box, however large, are clipped to it without any overflow
    (RuntimeWarnings are errors in this suite), in the env and in the vector env; both
    docstrings say so."""
    for cls in (SDJLSEnv, SDJLSVectorEnv):  # "are clipped to it" / "clipping of actions"
        assert "clip" in (cls.__doc__ or ""), f"{cls.__name__} does not document the clipping"
    bound = 200.0
    env = gym.make("SDJLS-Macro-v0")
    for value in EXTREME:
        env.reset(seed=0)
        _, reward, _, _, info = env.step(np.array([value]))
        assert info["u"].tolist() == [np.sign(value) * bound]
        assert np.isfinite(reward) and np.all(np.isfinite(info["state"]))
    envs = SDJLSVectorEnv(len(EXTREME), model="macro")
    envs.reset(seed=0)
    _, rewards, _, _, infos = envs.step(np.array(EXTREME)[:, None])
    np.testing.assert_array_equal(infos["u"][:, 0], np.sign(EXTREME) * bound)
    assert np.all(np.isfinite(rewards)) and np.all(np.isfinite(infos["state"]))
