"""SDJLSModel: the paper's example, (de)serialization, immutability, names, shared matrices.

Expected numbers come from the paper (typed into ``conftest.py``) or are computed by hand in
the test; nothing is copied from the code under test. The checks of bad input are in
``test_model_validation.py``, the dynamics and the mode sampling in ``test_model_dynamics.py``.
"""

from __future__ import annotations

import copy
import dataclasses
import pickle
import re

import numpy as np
import pytest
from conftest import raises_naming

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
    with raises_naming(InvalidModelError, "model field", ["A_typo"]):
        SDJLSModel.from_dict(data)


@pytest.mark.parametrize("name", ["A", "G", "x0"])
def test_from_dict_missing_field_is_named(paper_kwargs, name):
    data = SDJLSModel(**paper_kwargs).to_dict()
    del data[name]
    with raises_naming(InvalidModelError, "model field", [name]):
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
    with raises_naming(InvalidModelError, "model file", filename):
        load_model(path)


def test_file_with_a_bad_value_names_the_field(tmp_path, paper_kwargs):
    data = SDJLSModel(**paper_kwargs).to_dict()
    data["R"] = [[[1.0]], [[-1.2]], [[1.3]]]
    path = tmp_path / "bad_R.json"
    import json

    path.write_text(json.dumps(data))
    with raises_naming(InvalidModelError, ("bad_R.json", "R[1]"), -np.full((1, 1), 1.2)):
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


# --------------------------------------------------------------------------- names as labels
#: Names the model accepts: printable text, however exotic; each must survive both file formats.
PRINTABLE_NAMES = ["é ü", "line\u2028separator", "\ufeffbom", "emoji \U0001f600",
                   'quote " and \\ backslash', "\uffff", "\U0010ffff", "[x] = {y}", " "]  # fmt: skip


@pytest.mark.parametrize("bad", ["\x7f", "\ud800", "\x00", "a\nb", "\t", "\x85", "\udfff"])
@pytest.mark.parametrize("field", ["mode_names", "state_names"])
def test_a_name_with_a_control_character_or_a_lone_surrogate_is_refused(paper_kwargs, bad, field):
    """A name is a label: DEL (refused by TOML when written raw), a lone surrogate (no UTF-8
    file can hold it) and the other control characters are refused when the model is built."""
    size = 3 if field == "mode_names" else 2
    names = [f"name {i}" for i in range(size)]
    names[1] = f"x{bad}y"
    with raises_naming(InvalidModelError, f"{field}[1]", names[1]):
        SDJLSModel(**{**paper_kwargs, field: names})


@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_every_printable_name_round_trips_through_both_formats(tmp_path, paper_kwargs, suffix):
    for i in range(0, len(PRINTABLE_NAMES), 3):
        names = (PRINTABLE_NAMES[i : i + 3] + ["a", "b", "c"])[:3]
        model = SDJLSModel(**{**paper_kwargs, "mode_names": names,
                              "state_names": names[:2]})  # fmt: skip
        save_model(model, tmp_path / f"m{suffix}")
        loaded = load_model(tmp_path / f"m{suffix}")
        assert loaded == model and loaded.mode_names == tuple(names)


def test_load_model_names_a_folder(tmp_path):
    folder = tmp_path / "model.json"
    folder.mkdir()
    with raises_naming(InvalidModelError, "path", str(folder)):
        load_model(folder)
    with raises_naming(ValueError, "path", str(folder)):
        save_model(sdjls_gym.macro(), folder)


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
    with raises_naming(InvalidModelError, "state_names", ("a", "b", "c")):
        SDJLSModel(**{**paper_kwargs, "state_names": ("a", "b", "c")})
    with raises_naming(TypeError, "state_names", "ab"):
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


def test_readme_sections_named_in_the_sources_exist():
    """A pointer such as ``README, "Some section"`` or ``docs/page.md, "Some section"`` in
    ``sdjls_gym`` names a real heading of that file."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]

    def headings(name: str) -> set[str]:
        path = root / ("README.md" if name == "README" else name)
        return set(re.findall(r"^#+ (.+?)\s*$", path.read_text("utf-8"), re.M))

    pointers = []
    for path in sorted((root / "sdjls_gym").rglob("*.py")):
        text = " ".join(line.strip().lstrip("#:").strip() for line in path.read_text().splitlines())
        pointers += [
            (path.name, doc, name)
            for doc, name in re.findall(r'(README|docs/[a-z-]+\.md)[^".]{0,40}"([^"]+)"', text)
        ]
    assert pointers, "no README or docs pointer found: the test would be vacuous"
    missing = [(file, doc, name) for file, doc, name in pointers if name not in headings(doc)]
    assert missing == []
