"""Shared fixtures and helpers of the tests.

* the paper's example (``paper``, ``paper_kwargs``, ``quiet_paper_model``, ``paper_policy``),
  another model (``other_model``) and small hand-made models (``noiseless_model``,
  ``doubling_model``);
* random systems (``random_sdjls``), random problems P3 of the receding-horizon tests
  (``random_problem``) and two checks of an answer (``paper_cost``, ``assert_feasible``);
* ``raises_naming``: the one way the tests check an error (its type, the argument's name and
  the offending value, never the whole sentence), and ``no_solver`` / ``raised_by_library``
  for the error catalogues (``test_errors_*.py``);
* the tables the README and the documentation copy from the committed reports
  (``COPIED_TABLES``, ``uncopied_rows``).

Test modules import the plain functions (``from conftest import raises_naming``).

The numbers of the macroeconomic example are typed in from section 6 of the paper
(``/work/shared/paper/sdjls-rhc-paper.tex``), never imported from ``sdjls_gym``, so that a
wrong number in the preset makes a test fail. Modes are 0-based here (the paper's 1, 2, 3 are
0, 1, 2: normal, boom, slump).
"""

from __future__ import annotations

import os

# One BLAS thread, before numpy is imported (as benchmarks/__init__.py does for the scripts):
# the tests' matrices are small, and OpenBLAS threads fight over a shared machine's cores (a test
# heavy in eigendecompositions took 0.5 s with one thread and 7-16 s with the default at load 6).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import contextlib  # noqa: E402
import re  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from pathlib import Path  # noqa: E402
from types import SimpleNamespace  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from sdjls_gym import SDJLSModel  # noqa: E402


def paper_numbers() -> SimpleNamespace:
    """The numbers of the paper's example (``paper`` fixture; importable for module constants).

    Section 6: A_1..A_3, B, lambda, mu, G, H_k, x_0, Q_i, R_i, K_i, horizon."""
    return SimpleNamespace(
        A=np.array(
            [
                [[0.0, 1.0], [-2.5, 3.2]],
                [[0.0, 1.0], [-4.3, 4.5]],
                [[0.0, 1.0], [5.3, -5.2]],
            ]
        ),
        B=np.array([[0.0], [1.0]]),  # B = [0 1]', the same in every mode
        lam=np.array([[0.6, 0.3, 0.1], [0.25, 0.55, 0.2], [0.35, 0.15, 0.5]]),
        mu=np.array([[0.67, 0.17, 0.16], [0.30, 0.47, 0.23], [0.26, 0.10, 0.64]]),
        G=np.array([[0.0, -1.0], [0.0, 1.0]]),
        H=lambda k: np.array([-2.0 - 0.5 * k, 5.0 + 0.5 * k]),  # H_k
        x0=np.array([2.0, 2.0]),
        Q=np.array([np.eye(2), 1.1 * np.eye(2), 1.2 * np.eye(2)]),
        R=np.array([[[1.0]], [[1.2]], [[1.3]]]),
        K=np.array([[[2.5, -3.2]], [[4.3, -4.5]], [[-5.3, 5.2]]]),
        mode_names=("normal", "boom", "slump"),
        mode0=0,
        horizon=20,
    )


@pytest.fixture
def paper() -> SimpleNamespace:
    """The numbers of section 6 of the paper (a fresh copy per test)."""
    return paper_numbers()


def _paper_kwargs() -> dict:
    p = paper_numbers()
    return {
        "A": p.A,
        "B": p.B,
        "P_in": p.lam,
        "P_out": p.mu,
        "G": p.G,
        "H0": p.H(0),
        "H_rate": p.H(1) - p.H(0),
        "Q": p.Q,
        "R": p.R,
        "x0": p.x0,
        "E": np.eye(2),
        "W": np.eye(2),
        "mode0": p.mode0,
        "mode_names": p.mode_names,
    }


@pytest.fixture
def paper_kwargs() -> dict:
    """``SDJLSModel(**paper_kwargs)`` is the paper's example (E = I, W = I given explicitly)."""
    return _paper_kwargs()


@pytest.fixture
def quiet_paper_model() -> SDJLSModel:
    """The paper's example with W = 0: ``x_{k+1} = A x_k + B u_k`` exactly, modes still random."""
    return SDJLSModel(**{**_paper_kwargs(), "W": np.zeros((2, 2))})


@pytest.fixture
def paper_policy():
    """``u_k = K_theta x_k + nu_k`` with the paper's gains and ``nu_k = 3.5 + 0.5 k``.

    ``A_i + B K_i = [[0, 1], [0, 0]]`` in every mode, so the income is ``x_{k+1}(2) = nu_k +
    w_k(2)``, half a unit under the middle of the band. Works on one state or on a batch.
    """
    K = paper_numbers().K

    def policy(state, mode, k):
        state = np.asarray(state, dtype=np.float64)
        nu = 3.5 + 0.5 * np.asarray(k, dtype=np.float64)
        return np.einsum("...ij,...j->...i", K[np.asarray(mode)], state) + nu[..., None]

    return policy


@pytest.fixture
def info_policy(paper_policy):
    """The paper's feedback, as a function of the info of the current state."""

    def policy(info):
        return paper_policy(info["state"], info["mode"], info["k"]).astype(np.float32)

    return policy


def run_episode(env, policy, seed=None, steps=None) -> dict:
    """Run ``policy(info)`` from a reset; lists of observations, rewards, flags and infos."""
    obs, info = env.reset(seed=seed)
    out = {"obs": [obs], "reward": [], "flags": [], "info": [info]}
    k = 0
    while steps is None or k < steps:
        obs, reward, terminated, truncated, info = env.step(policy(info))
        out["obs"].append(obs)
        out["reward"].append(reward)
        out["flags"].append((terminated, truncated))
        out["info"].append(info)
        k += 1
        if terminated or truncated:
            break
    return out


def assert_same_info(a: dict, b: dict) -> None:
    """The same keys, values and value types."""
    assert a.keys() == b.keys()
    for key in a:
        assert np.array_equal(a[key], b[key]), key
        assert type(a[key]) is type(b[key]), key


def assert_same_episode(a: dict, b: dict) -> None:
    """Two ``run_episode`` results are bit-identical."""
    assert len(a["obs"]) == len(b["obs"])
    for x, y in zip(a["obs"], b["obs"], strict=True):
        assert x.dtype == y.dtype and np.array_equal(x, y)  # bit-identical
    assert a["reward"] == b["reward"]
    assert a["flags"] == b["flags"]
    for x, y in zip(a["info"], b["info"], strict=True):
        assert_same_info(x, y)


def _other_model() -> SDJLSModel:
    """A model unlike the paper's: N = 2, n = 3, m = 2, p = 1, r = 3, random initial mode."""
    return SDJLSModel(
        A=[
            [[0.9, 0.1, 0.0], [0.0, 0.8, 0.1], [0.0, 0.0, 0.7]],
            [[1.05, 0.0, 0.2], [0.1, 0.9, 0.0], [0.0, 0.3, 0.6]],
        ],
        B=[[[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]], [[0.5, 0.0], [0.0, 1.0], [0.2, 0.2]]],
        P_in=[[0.9, 0.1], [0.4, 0.6]],
        P_out=[[0.2, 0.8], [0.05, 0.95]],
        G=[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [1.0, 1.0, 1.0]],
        H0=[1.0, 1.0, 2.0],
        H_rate=[0.1, 0.0, -0.05],
        Q=[[2.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]],
        R=[np.eye(2), [[2.0, 0.3], [0.3, 1.0]]],
        x0=[0.5, -0.2, 0.1],
        E=[[[1.0], [0.0], [0.5]], [[0.0], [1.0], [1.0]]],
        W=[[0.25]],
        mode0=[0.3, 0.7],
        mode_names=("calm", "stormy"),
    )


@pytest.fixture
def other_model() -> SDJLSModel:
    """A second, structurally different model (every optional field set)."""
    return _other_model()


def noiseless_model(
    A,
    *,
    B=((0.0,), (1.0,)),
    G=((0.0, 1.0),),
    H0=None,
    Q=None,
    x0=(1e6, 1e6),
) -> SDJLSModel:
    """One mode, ``n = 2``, ``W = 0``: ``x_{k+1} = A x_k + B u_k`` exactly (no noise).

    The model of the overflow tests (entries near 1e303 in ``A`` or ``Q``). ``H0`` is 1e9 per
    row of ``G`` unless given: far from the states of the tests.
    """
    G = [list(row) for row in G]
    return SDJLSModel(
        A=[A], B=[list(row) for row in B], P_in=[[1.0]], P_out=[[1.0]], G=G,
        H0=[1e9] * len(G) if H0 is None else H0, Q=np.eye(2) if Q is None else Q, R=[[1.0]],
        x0=list(x0), W=np.zeros((2, 2)),
    )  # fmt: skip


def doubling_model() -> SDJLSModel:
    """``x_{k+1} = 2 x_k + u_k`` from ``x_0 = 1``, one mode, ``n = m = 1``, no noise, band
    ``x <= 100``: 2, 4, 8, 16 under ``u = 0``."""
    return SDJLSModel(
        A=[[[2.0]]], B=[[1.0]], P_in=[[1.0]], P_out=[[1.0]], G=[[1.0]], H0=[100.0],
        Q=[[1.0]], R=[[1.0]], x0=[1.0], W=[[0.0]],
    )  # fmt: skip


# -------------------------------------------------------------------------- random P3 problems
def random_sdjls(
    rng: np.random.Generator,
    N: int,
    n: int,
    m: int,
    p: int,
    r: int,
    *,
    a_scale: float = 0.7,
    weights: bool = True,
) -> SDJLSModel:
    """A random SDJLS with E != I and W != I (full rank W), ``A`` of entries ``N(0, a_scale^2)``;
    random weights ``Q``, ``R`` (``weights``) or identities."""
    L = rng.normal(size=(p, p))
    M = rng.normal(size=(N, m, m)) if weights else None
    return SDJLSModel(
        A=rng.normal(size=(N, n, n)) * a_scale,
        B=rng.normal(size=(N, n, m)),
        E=rng.normal(size=(N, n, p)),
        W=L @ L.T + 0.2 * np.eye(p),
        P_in=rng.dirichlet(np.ones(N), size=N),
        P_out=rng.dirichlet(np.ones(N), size=N),
        G=rng.normal(size=(r, n)),
        H0=rng.uniform(1.0, 3.0, size=r),
        H_rate=rng.uniform(-0.1, 0.1, size=r),
        Q=np.eye(n) * rng.uniform(0.5, 2.0) if weights else np.eye(n),
        R=np.eye(m) if M is None else M @ M.transpose(0, 2, 1) + 0.3 * np.eye(m),
        x0=np.zeros(n),
    )


def random_problem(seed: int):
    """A random system (n <= 4, m <= 2, N <= 3, r <= 4), random K (stabilising or not), Psi."""
    rng = np.random.default_rng(seed)
    N, n, m = int(rng.integers(1, 4)), int(rng.integers(1, 5)), int(rng.integers(1, 3))
    p, r = int(rng.integers(1, 5)), int(rng.integers(1, 5))
    model = random_sdjls(rng, N, n, m, p, r)
    K = rng.normal(size=(N, m, n))
    S = rng.normal(size=(N, n, n))
    Psi = S @ S.transpose(0, 2, 1) + 0.5 * np.eye(n)
    return rng, model, K, Psi


def paper_cost(model, K, Psi, alpha, x, mode, k, nu, rho):
    """J_k of P3 written out term by term: stage cost + sum_j pi_j E[x' Psi_j x] + alpha rho."""
    u = K[mode] @ x + nu
    pi = model.transition_rows(x, mode, k)
    mean = model.next_state(x, mode, u, np.zeros(model.p))
    cov = model.E[mode] @ model.W @ model.E[mode].T
    terminal = sum(pi[j] * (mean @ Psi[j] @ mean + np.trace(Psi[j] @ cov)) for j in range(model.N))
    return x @ model.Q[mode] @ x + u @ model.R[mode] @ u + terminal + alpha * rho


def assert_feasible(ctrl, x, mode, k, u, info, tol=1e-7):
    """(nu, rho) satisfies nu in U, rho >= 0 and every tightened row on x_{k+1}."""
    model = ctrl.model
    nu, rho = info["nu"], info["rho"]
    np.testing.assert_allclose(u, ctrl.K[mode] @ x + nu, rtol=0, atol=1e-12)
    assert rho >= 0.0
    if ctrl.nu_set == "box" or model.m == 1:
        assert np.all(np.abs(nu) <= ctrl.nu_bound + tol)
    else:
        assert np.linalg.norm(nu) <= ctrl.nu_bound + tol
    if ctrl.tightening is not None:
        mean = model.next_state(x, mode, u, np.zeros(model.p))
        slack = model.H(k + 1) - ctrl.tightening[mode] + rho - model.G @ mean
        assert np.all(slack >= -tol * max(1.0, np.max(np.abs(model.H(k + 1))))), slack


# ------------------------------------------------------------------------------------ errors
class _Unshown:
    def __repr__(self) -> str:
        return "UNSHOWN"


UNSHOWN: Any = _Unshown()
"""``raises_naming(..., value=UNSHOWN)``: the message does not show the offending value (a
known gap of that message, listed where it is used); only the type and the name are checked."""

_LONG = 60  # a value written with more characters is shown shortened: its start must appear


def shown_as(value: Any) -> list[str]:
    """The ways a message may write ``value``: its ``repr`` or ``str`` (a ``str`` value as it
    is or quoted), an array as numpy writes it with ``", "`` between entries (4 to 8 digits) or
    as a list; runs of white space count as one space."""
    if isinstance(value, str):
        texts = [value, repr(value)]
    elif isinstance(value, np.ndarray):
        texts = [np.array2string(value, separator=", ", precision=p) for p in range(4, 9)]
        texts += [repr(value.tolist()), repr(value)]
    else:
        texts = [repr(value), str(value)]
        if isinstance(value, float | np.floating) and "e" in format(value, "g"):
            texts.append(format(value, "g"))  # 2e+06 for 2000000.0
    return [" ".join(text.split()) for text in texts]


_NEAR = 160  # the value starts at most this many characters after the name


def _token(text: str) -> re.Pattern[str]:
    """``text`` as a whole token: ``1`` is not found in ``-1``, ``1.5``, ``10`` or ``x1``, ``k``
    not in ``rank``. A long text needs only its start (values are shown shortened)."""
    if len(text) > _LONG:
        text, end = text[:20], ""
    else:
        end = r"(?![\w]|\.\d)" if text[-1:].isalnum() or text.endswith("_") else ""
    start = r"(?<![\w.+-])" if text[:1].isalnum() or text.startswith("_") else ""
    return re.compile(start + re.escape(text) + end)


def _appears(text: str, message: str) -> bool:
    return _token(text).search(message) is not None


def _shown_after(names: tuple[str, ...], texts: list[str], message: str) -> bool:
    """One of ``texts`` follows one of the ``names`` within ``_NEAR`` characters: the value
    belongs to the argument (``xi = 1.5``, ``K has shape (3, 2)``), not to the explanation
    further on (``... xi = 1 cannot be met``) or to another argument."""
    for name in names:
        for found in _token(name).finditer(message):
            for text in texts:
                shown = _token(text).search(message, found.end())
                if shown and shown.start() - found.end() <= _NEAR:
                    return True
    return False


@contextlib.contextmanager
def raises_naming(
    exc_type: type[BaseException] | tuple[type[BaseException], ...],
    name: str | tuple[str, ...],
    value: Any,
) -> Iterator[pytest.ExceptionInfo]:
    """The block raises ``exc_type`` (or a subclass) whose message names the argument ``name``
    (each of several names) and shows the offending ``value`` after it (see :func:`shown_as`).

    The project's rule for errors (STYLE.md): a test asserts the type, the name and the value,
    not the sentence around them, so messages may be reworded without touching the tests.
    """
    with pytest.raises(exc_type) as excinfo:
        yield excinfo
    message = " ".join(str(excinfo.value).split())
    kind = type(excinfo.value).__name__
    names = (name,) if isinstance(name, str) else name
    for each in names:
        assert _appears(each, message), f"{kind} does not name {each!r}: {message!r}"
    if value is not UNSHOWN:
        texts = shown_as(value)
        assert _shown_after(names, texts, message), (
            f"{kind} does not show the value ({' or '.join(texts)}) after "
            f"{' or '.join(map(repr, names))}: {message!r}"
        )


class SolverCalled(BaseException):
    """Raised by the trap of ``no_solver``; a BaseException, which no ``except Exception`` in
    the library can hide."""


@pytest.fixture
def no_solver(monkeypatch):
    """Every solver (OSQP, cvxpy) replaced by a trap: bad input must be refused before any."""
    import cvxpy as cp
    import osqp

    def trap(*args, **kwargs):
        raise SolverCalled("a solver was started before the bad input was rejected")

    monkeypatch.setattr(osqp.OSQP, "solve", trap)
    monkeypatch.setattr(cp.Problem, "solve", trap)


def raised_by_library(excinfo: pytest.ExceptionInfo, dirs=("sdjls_gym", "controllers")) -> None:
    """The innermost frame of the traceback is in the project's own code (one of ``dirs``):
    a check of this project refused the input, not numpy, scipy or cvxpy deep inside."""
    innermost = excinfo.traceback[-1]
    parts = Path(str(innermost.path)).parts
    assert "site-packages" not in parts and any(d in parts for d in dirs), (
        f"{type(excinfo.value).__name__} raised from {innermost.path}:{innermost.lineno + 1}, "
        f"not from a check in {' or '.join(d + '/' for d in dirs)}"
    )


def refused(error, name, value, call, dirs=("sdjls_gym", "controllers")) -> pytest.ExceptionInfo:
    """``call()`` raises ``error`` naming ``name`` and showing ``value`` (:func:`raises_naming`:
    not the sentence around them), with no warning on the way, from a check in the project's own
    code (``dirs``: the innermost traceback frame is there, not deep inside numpy, scipy or
    cvxpy). The error catalogues (``test_errors_*.py``) check every case with it, under the
    :func:`no_solver` trap (``osqp.OSQP.solve`` and ``cvxpy.Problem.solve`` replaced: no solver
    may start before the error)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning on the way to the error either
        with raises_naming(error, name, value) as excinfo:
            call()
    raised_by_library(excinfo, dirs)
    return excinfo


# Hypothesis (6.1xx) also seeds its examples with constants mined from the project's own modules
# (every literal of every loaded local module), so a derandomized test would draw other examples
# whenever any literal in the repository changes or another set of modules is loaded (a single
# test file against the whole suite). Keep the draws a function of the test alone.
try:
    from hypothesis.internal.conjecture import providers as _hypothesis_providers

    _hypothesis_providers._get_local_constants = lambda: _hypothesis_providers._local_constants
except (ImportError, AttributeError):  # another Hypothesis version: nothing to pin
    pass


# ----------------------------------------------------------------------------- copied tables
#: The sections of the README and of ``docs/benchmarks.md`` whose tables are copies of a
#: committed report's: ``(title, report, rows the README shows at least, rows the docs show)``.
COPIED_TABLES = (
    ("Reproducing the paper (section 6)", "results/paper/REPORT.md", 8, 8),
    ("Receding horizon against reinforcement learning", "results/rl/REPORT.md", 6, 20),
    ("Speed", "results/speed/SPEED.md", 6, 14),
    ("The suite, scored as one benchmark", "results/suite/REPORT.md", 8, 12),
    ("Learn the model, then control", "results/identify/REPORT.md", 8, 8),
    ("The mode hidden", "results/hidden/REPORT.md", 8, 8),
)


def section(text: str, title: str) -> str:
    """The Markdown ``text`` from the ``## title`` heading to the next ``## `` heading."""
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, flags=re.M | re.S)
    assert match, f"no section '## {title}'"
    return match.group(1)


def uncopied_rows(page: str, title: str, report: Path, min_rows: int) -> list[str]:
    """The table rows of the section ``title`` of the Markdown ``page`` that are not rows of
    ``report``, after checking that the section shows at least ``min_rows``."""

    def rows(text: str) -> list[str]:
        return [line.strip() for line in text.splitlines() if line.strip().startswith("|")]

    shown = rows(section(page, title))
    assert len(shown) >= min_rows, f"'{title}' shows {len(shown)} table rows"
    report_rows = set(rows(report.read_text(encoding="utf-8")))
    return [row for row in shown if row not in report_rows]
