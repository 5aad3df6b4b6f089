"""The structure of the three packages together (issue 32), read from the source with ``ast``:
no import cycle between modules, no private name taken from another module, the scoring without
stable-baselines3, one builder of command lines from dataclasses, names that do not shadow
another library's.

An import counts wherever it is written, at the top of a module or inside a function: a lazy
import is still a dependency (and the way a cycle hides). :mod:`tests.test_structure` checks
``sdjls_gym`` alone.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import textwrap

import pytest
from test_structure import ROOT, imports, internal_graph, modules

PACKAGES = ("sdjls_gym", "controllers", "benchmarks")
#: The package faces (``__init__`` files) hand names on; a cycle through one is a cycle of the
#: modules it names, checked without it.
FACES = {
    "sdjls_gym",
    "sdjls_gym.systems",
    "controllers",
    "benchmarks",
    "benchmarks.core",
    "benchmarks.suite",
    "benchmarks.speed",
    "benchmarks.identify",
    "benchmarks.hidden",
}
#: The wings of ``benchmarks``: each assembles the core's pieces into one study.
WINGS = ("hidden", "identify", "paper", "pictures", "rl", "speed", "suite")


def import_graph() -> dict[str, set[str]]:
    """module -> the modules of the three packages it imports, anywhere in its source."""
    return internal_graph(*PACKAGES)


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def test_the_checks_see_lazy_imports_and_cycles():
    """The checks below can fail: an import inside a function is an edge, and a cycle of two
    or three modules is found."""
    lazy = imports(ROOT / "benchmarks" / "suite" / "cli.py")  # main() imports the report lazily
    assert ("benchmarks.suite.report", "run_references") in lazy
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


@pytest.mark.parametrize(
    "package",
    [
        "sdjls_gym",
        "benchmarks",
        "controllers",
    ],
)
def test_no_import_cycle_between_modules(package):
    graph = {m: ts - FACES for m, ts in import_graph().items() if m not in FACES}
    within = [c for c in cycles(graph) if any(m.split(".")[0] == package for m in c)]
    assert not within, f"import cycles: {within}"


def test_no_package_imports_a_package_above_it():
    """model -> env -> controllers -> benchmarks: no back-edge between the packages."""
    order = {p: i for i, p in enumerate(PACKAGES)}
    back = sorted(
        f"{m} -> {t}"
        for m, ts in import_graph().items()
        for t in ts
        if order[t.split(".")[0]] > order[m.split(".")[0]]
    )
    assert not back, back


def _layer(module: str) -> str:
    """``core``, a wing's name, or ``entry`` (the package face and the ``python -m`` entry
    points at the top of ``benchmarks``)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in ("core", *WINGS) else "entry"


def test_the_scoring_core_imports_no_wing_and_no_wing_another():
    """benchmarks/core is the protocol, owned once: it imports no wing and no entry point; a
    wing imports the core (and sdjls_gym, controllers), and of another wing only its package
    face (the names its ``__init__`` exports), never its modules."""
    wrong = sorted(
        f"{m} -> {t}"
        for m, ts in import_graph().items()
        if m.startswith("benchmarks.")
        for t in ts
        if t.startswith("benchmarks.")
        and _layer(t) != _layer(m)
        and _layer(t) != "core"
        and _layer(m) != "entry"
        and not (_layer(m) != "core" and t == f"benchmarks.{_layer(t)}")
    )
    assert not wrong, wrong
    layers = {_layer(m) for m in modules("benchmarks") if m != "benchmarks"}
    assert layers == {"core", "entry", *WINGS}, layers


def test_the_entry_points_are_thin():
    """The modules at the top of benchmarks hand over to a wing: a few lines each, except the
    public face of the protocol (benchmarks/evaluate.py, which holds the command line)."""
    sizes = {
        name: len(path.read_text(encoding="utf-8").splitlines())
        for name, path in modules("benchmarks").items()
        if _layer(name) == "entry" and name not in ("benchmarks", "benchmarks.evaluate")
    }
    assert max(sizes.values()) <= 60, sizes


def _private_imports(package: str) -> list[str]:
    """``from m import _x`` (or a private module) where ``m`` is another module of the three
    packages."""
    found = []
    for name, path in modules(package).items():
        for module, imported in imports(path):
            if module.split(".")[0] not in PACKAGES or module == name:
                continue
            private_module = any(part.startswith("_") for part in module.split("."))
            if private_module or (imported is not None and imported.startswith("_")):
                found.append(f"{name}: from {module} import {imported}")
    return found


def _private_reads(package: str) -> dict[str, list[str]]:
    """module -> its reads of ``obj._private`` where ``obj`` is not ``self``, ``cls`` or
    ``super()`` (another object's private state)."""
    found: dict[str, list[str]] = {}
    for name, path in modules(package).items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if not (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
            ):
                continue
            owner = node.value
            if isinstance(owner, ast.Name) and owner.id in ("self", "cls"):
                continue
            if isinstance(owner, ast.Call) and ast.unparse(owner.func) == "super":
                continue
            found.setdefault(name, []).append(f"{node.lineno}: {ast.unparse(node)}")
    return found


def test_benchmarks_import_no_private_name_of_another_module():
    assert not _private_imports("benchmarks"), _private_imports("benchmarks")


def test_benchmarks_read_no_private_attribute():
    reads = _private_reads("benchmarks")
    assert not reads, reads


# ----------------------------------------------------------------------------- base install
BLOCK_RL = textwrap.dedent(
    """
    import sys

    class NoRL:
        \"\"\"stable-baselines3 and torch are not installed, as in the base install.\"\"\"

        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("stable_baselines3", "torch"):
                raise ImportError(f"No module named {name!r} (blocked by the test)")
            return None

    sys.meta_path.insert(0, NoRL())
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        pass
    else:
        raise SystemExit("the block does not work")
    """
)


def test_evaluate_and_the_suite_run_without_stable_baselines3(tmp_path):
    """``python -m benchmarks.evaluate`` on a controller and ``evaluate_suite`` on a callable,
    2 episodes each, with stable-baselines3 and torch unimportable."""
    (tmp_path / "no_rl_policies.py").write_text(
        textwrap.dedent(
            """
            import numpy as np

            from controllers import LinearFeedbackController
            from sdjls_gym.systems.macro import PAPER_K, macro

            controller = LinearFeedbackController(macro(), PAPER_K)


            def zero_policy(task):
                return lambda obs: np.zeros(task.model.m)
            """
        )
    )
    script = BLOCK_RL + textwrap.dedent(
        """
        from benchmarks.evaluate import main
        from benchmarks.suite import evaluate_suite
        import no_rl_policies

        score = main(["--policy", "no_rl_policies:controller", "--episodes", "2"])
        assert score.episodes == 2, score
        suite = evaluate_suite(no_rl_policies.zero_policy, tasks=("SDJLS-Solar-v0",), episodes=2)
        assert len(suite.results) == 1, suite
        loaded = sorted(m for m in sys.modules if m.startswith(("stable_baselines3", "torch")))
        assert not loaded, loaded
        print("scored without stable-baselines3")
        """
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(tmp_path)])}
    env["MPLBACKEND"] = "Agg"
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert "scored without stable-baselines3" in done.stdout


# ----------------------------------------------------------------------------- command lines
def test_one_builder_makes_the_command_lines_of_dataclasses():
    """No script builds ``argparse`` options from a dataclass's fields by itself:
    :func:`benchmarks.core.cli.options_parser` does, for all of them."""
    builders = []
    for name, path in modules("benchmarks").items():
        if name == "benchmarks.core.cli":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.For) and "fields(" in ast.unparse(node.iter):
                if "add_argument" in ast.unparse(node):
                    builders.append(f"{name}:{node.lineno}")
    assert not builders, builders


# ----------------------------------------------------------------------------- names
def test_evaluate_names_shadow_neither_the_stdlib_nor_gymnasium():
    import benchmarks.evaluate as ev

    assert not hasattr(ev, "statistics")  # the standard library's module
    assert not hasattr(ev, "EnvSpec")  # gymnasium.envs.registration.EnvSpec
    assert callable(ev.rollout_statistics) and isinstance(ev.TaskEnv, type)


def test_a_state_row_is_not_called_xi():
    """``xi`` is the paper's confidence level; a loop over the rows of states names them
    otherwise."""
    found = []
    for name, path in modules("benchmarks").items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, (ast.For, ast.comprehension)) and isinstance(
                node.target, ast.Tuple
            ):
                names = [t.id for t in node.target.elts if isinstance(t, ast.Name)]
                if "xi" in names and "zip(x," in ast.unparse(node.iter).replace(" ", " "):
                    found.append(f"{name}: {ast.unparse(node.target)}")
    assert not found, found


@pytest.mark.parametrize("package", ["controllers", "benchmarks"])
def test_module_sizes(package):
    sizes = {
        name: len(path.read_text(encoding="utf-8").splitlines())
        for name, path in modules(package).items()
    }
    assert max(sizes.values()) <= 600, {k: v for k, v in sizes.items() if v > 600}


def test_no_test_file_passes_800_lines():
    sizes = {
        p.name: len(p.read_text(encoding="utf-8").splitlines()) for p in ROOT.glob("tests/*.py")
    }
    assert max(sizes.values()) <= 800, {k: v for k, v in sizes.items() if v > 800}


def test_one_hand_written_lru():
    """The caches functools cannot be share controllers/lru.py's BudgetedLRU; no module keeps
    another hand-written one (an OrderedDict moved to its end and popped from its start)."""
    found = [
        name
        for name, path in modules(*PACKAGES).items()
        if name != "controllers.lru" and "OrderedDict" in path.read_text(encoding="utf-8")
    ]
    assert not found, found
