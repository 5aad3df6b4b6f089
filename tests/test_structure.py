"""The structure of ``sdjls_gym`` that issue 32 asks for, read from the source with ``ast``.

* no import cycle between its modules (imports inside functions count: a lazy import is still
  a dependency);
* no private name crosses a module boundary (``from m import _x``, ``m._x``, a private
  module), in ``sdjls_gym`` and in what ``controllers`` and ``benchmarks`` take from it;
* every exception class of ``sdjls_gym`` and ``controllers`` lives in ``sdjls_gym/errors.py``,
  on builtin bases;
* the controllers import the model, never the environments;
* no module reads another library's private frames;
* no module of ``sdjls_gym`` passes 600 lines.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "sdjls_gym"
MAX_LINES = 600


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules(*packages: str) -> dict[str, Path]:
    return {module_name(p): p for pkg in packages for p in sorted((ROOT / pkg).rglob("*.py"))}


def imports(path: Path) -> list[tuple[str, str | None]]:
    """``(module, name)`` for every import in the file, ``name`` None for ``import module``;
    relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = (
        module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    )
    out: list[tuple[str, str | None]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, None) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            out += [(base, alias.name) for alias in node.names]
    return out


def internal_graph(*packages: str) -> dict[str, set[str]]:
    """module -> the modules of ``packages`` (default ``sdjls_gym``) it imports (a package's
    submodule imported by ``from package import submodule`` counts as the submodule)."""
    known = modules(*(packages or ("sdjls_gym",)))
    graph: dict[str, set[str]] = {}
    for name, path in known.items():
        targets = set()
        for module, imported in imports(path):
            if imported is not None and f"{module}.{imported}" in known:
                targets.add(f"{module}.{imported}")
            elif module in known:
                targets.add(module)
        targets.discard(name)
        graph[name] = targets
    return graph


def test_no_import_cycle_in_sdjls_gym():
    graph = internal_graph()
    # the package faces (__init__ files) hand names on and are imported by their submodules'
    # users; a cycle through one is a cycle of the modules it names, checked without it
    faces = {"sdjls_gym", "sdjls_gym.systems"}
    graph = {m: {t for t in ts if t not in faces} for m, ts in graph.items() if m not in faces}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if state.get(target) == 1:
                cycle = stack[stack.index(target) :] + [target]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if target not in state:
                visit(target)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)


def test_no_private_name_crosses_a_module():
    found = []
    for name, path in modules("sdjls_gym", "controllers", "benchmarks").items():
        for module, imported in imports(path):
            if not module.startswith("sdjls_gym"):
                continue
            private_module = any(part.startswith("_") for part in module.split("."))
            if private_module or (imported is not None and imported.startswith("_")):
                found.append(f"{name}: from {module} import {imported}")
        if not name.startswith("sdjls_gym"):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):  # obj._private of an object that is not self or cls
            if (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
            ):
                found.append(f"{name}:{node.lineno}: .{node.attr}")
    assert not found, "\n".join(found)


def test_every_exception_lives_in_the_errors_module():
    import sdjls_gym.errors

    defined = []
    for name, path in modules("sdjls_gym", "controllers").items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef) and any(
                isinstance(base, ast.Name) and base.id.endswith(("Error", "Exception", "Needed"))
                for base in node.bases
            ):
                defined.append(f"{name}.{node.name}")
    errors = [f"sdjls_gym.errors.{n}" for n in sdjls_gym.errors.__all__]
    assert sorted(defined) == sorted(errors)
    for n in sdjls_gym.errors.__all__:
        cls = getattr(sdjls_gym.errors, n)
        assert issubclass(cls, (ValueError, TypeError, RuntimeError)), n
        assert cls.__doc__, n


def test_controllers_import_the_model_not_the_environments():
    for name, path in modules("controllers").items():
        for module, imported in imports(path):
            full = f"{module}.{imported}" if imported else module
            for env_module in ("sdjls_gym.env", "sdjls_gym.vector_env", "sdjls_gym.wrappers"):
                assert not (module == env_module or full == env_module), f"{name} imports {full}"
            assert not (module == "sdjls_gym" and imported in ("SDJLSEnv", "SDJLSVectorEnv")), name


def test_no_module_reads_another_librarys_private_frames():
    """Nothing reads a caller's frame or its local variables (the environment once read
    ``gymnasium.make``'s to refuse a long ``TimeLimit``)."""
    for name, path in modules("sdjls_gym", "controllers", "benchmarks").items():
        text = path.read_text(encoding="utf-8")
        for word in ("_getframe", "f_locals", "f_back", "currentframe"):
            assert word not in text, f"{name} uses {word}"


def test_no_module_of_sdjls_gym_passes_600_lines():
    sizes = {
        name: len(path.read_text(encoding="utf-8").splitlines())
        for name, path in modules("sdjls_gym").items()
    }
    assert max(sizes.values()) <= MAX_LINES, {k: v for k, v in sizes.items() if v > MAX_LINES}
