"""The documentation site (issue 33): every public name in the API reference, pages whose code
runs and whose tables are the committed reports, the files a project ships, console commands.

The tests that need the built site build it with ``mkdocs build --strict`` (the ``docs`` extra;
skipped without it), or read the one ``.ci/run`` built (``SDJLS_DOCS_SITE``).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import COPIED_TABLES, uncopied_rows

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _load_hooks():
    spec = importlib.util.spec_from_file_location("sdjls_docs_hooks", DOCS / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


hooks = _load_hooks()
PAGES = sorted(DOCS.glob("*.md"))


# ----------------------------------------------------------------------------- the reference
def test_every_module_has_a_line_in_the_reference():
    """A new module of sdjls_gym, controllers or benchmarks fails here until a reference page
    has its ``::: module`` line."""
    documented = hooks.documented_modules()
    missing = [m for m in hooks.all_modules() if m not in documented]
    assert not missing, f"modules without a '::: module' line in docs/reference/*.md: {missing}"
    stale = [m for m in documented if m not in hooks.all_modules()]
    assert not stale, f"docs/reference names modules that do not exist: {stale}"


def test_every_reference_page_is_in_the_navigation():
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    for page in sorted((DOCS / "reference").glob("*.md")):
        assert f"reference/{page.name}" in nav, f"{page.name} is not in mkdocs.yml's nav"
    for page in PAGES:
        assert f": {page.name}" in nav, f"{page.name} is not in mkdocs.yml's nav"


def _runtime_all(module: str) -> list[str] | None:
    try:
        return getattr(importlib.import_module(module), "__all__", None)
    except ImportError as exc:  # an optional dependency of a benchmark script
        pytest.skip(f"{module} does not import here ({exc}); its __all__ is read from source")


@pytest.mark.parametrize("module", hooks.all_modules())
def test_the_reference_reads_each_modules_all_as_python_does(module):
    """The reference's list of a module's public names (parsed from its source) is its
    ``__all__`` at run time."""
    static = hooks.module_names(module).all
    runtime = _runtime_all(module)
    assert (None if static is None else list(static)) == (
        None if runtime is None else list(runtime)
    )


@pytest.mark.parametrize("module", hooks.all_modules())
def test_public_functions_and_classes_have_docstrings(module):
    """What the reference shows of a function or class is its docstring."""
    names = hooks.module_names(module).all
    if names is None:
        return
    mod = importlib.import_module(module) if _runtime_all(module) is not None else None
    undocumented = []
    for name in names:
        obj = getattr(mod, name)
        if (inspect.isclass(obj) or inspect.isfunction(obj)) and not (obj.__doc__ or "").strip():
            undocumented.append(name)
    assert not undocumented, f"{module}: no docstring for {undocumented}"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The built site: ``SDJLS_DOCS_SITE`` (built by .ci/run), else ``mkdocs build --strict``."""
    given = os.environ.get("SDJLS_DOCS_SITE")
    if given:
        path = Path(given) if Path(given).is_absolute() else ROOT / given
        assert (path / "index.html").is_file(), f"SDJLS_DOCS_SITE={given} holds no built site"
        return path
    for package in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python"):
        pytest.importorskip(package, reason='the docs extra: pip install -e ".[docs]"')
    out = tmp_path_factory.mktemp("site")
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        check=False,
    )
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stderr[-3000:]}"
    return out


@pytest.mark.slow
def test_every_public_name_has_its_entry_in_the_built_reference(site):
    """Every module's heading, and every name of every ``__all__``: under the module, or (a
    re-export) where it is defined, linked from the module's table."""
    ids = set()
    for page in (site / "reference").rglob("*.html"):
        ids |= set(re.findall(r'id="([\w.]+)"', page.read_text(encoding="utf-8")))
    missing = []
    for module in hooks.all_modules():
        if module not in ids:
            missing.append(module)
        for name in hooks.module_names(module).all or ():
            anchor = hooks.reference_anchor(module, name)
            if anchor not in ids:
                missing.append(f"{module}.{name} (at {anchor})")
    assert not missing, f"not in the built reference: {missing}"


@pytest.mark.slow
def test_the_built_site_has_every_page_and_figure(site):
    for page in PAGES:
        name = "index.html" if page.stem == "index" else f"{page.stem}/index.html"
        assert (site / name).is_file(), name
    assert (site / "results/render/macro_rhc.png").is_file()
    assert (site / "img/tree_plan.png").is_file()
    changelog = (site / "changelog/index.html").read_text(encoding="utf-8")
    assert "Unreleased" in changelog  # CHANGELOG.md included, not a copy


# ----------------------------------------------------------------------------- the pages
def _python_blocks() -> list[tuple[str, int, str]]:
    out = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for i, block in enumerate(re.findall(r"```python\n(.*?)```", text, flags=re.S)):
            out.append((page.name, i, block))
    return out


def _expected_output(block: str) -> list[list[str] | None]:
    """For each ``print`` line, the tokens its comment says it prints (before a colon), or None
    when it has no comment."""
    expected = []
    for line in block.splitlines():
        if line.startswith("print("):
            comment = line.partition("  # ")[2]
            expected.append(comment.split(":")[0].split() if comment else None)
    return expected


@pytest.mark.parametrize(
    "block",
    [
        pytest.param(b, id=f"{page}-{i}", marks=[pytest.mark.slow] if ".learn(" in b else [])
        for page, i, b in _python_blocks()
    ],
)
def test_docs_python_examples_run_and_print_what_they_say(block, tmp_path, monkeypatch, capsys):
    """Every ```python block of the pages runs as written (in a scratch folder), and a ``print``
    whose comment gives values prints them."""
    if "stable_baselines3" in block:
        pytest.importorskip("stable_baselines3")
    monkeypatch.chdir(tmp_path)
    exec(compile(block, "docs python block", "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    expected = _expected_output(block)
    assert len(printed) == len(expected), printed
    for line, tokens in zip(printed, expected, strict=True):
        if tokens is not None:
            assert line.split() == tokens


@pytest.mark.parametrize(
    ("title", "report", "min_rows"), [(t[0], t[1], t[3]) for t in COPIED_TABLES]
)
def test_benchmark_tables_are_copied_from_the_committed_reports(title, report, min_rows):
    page = (DOCS / "benchmarks.md").read_text(encoding="utf-8")
    missing = uncopied_rows(page, title, ROOT / report, min_rows)
    assert not missing, f"rows not in {report} (re-copy them from it): {missing[:3]}"


def test_figures_exist_and_name_their_command():
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for figure in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):
            path = ROOT / figure if figure.startswith("results/") else DOCS / figure
            assert path.is_file(), f"{page.name} shows {figure}, which does not exist"
    controllers = (DOCS / "controllers.md").read_text(encoding="utf-8")
    assert "img/tree_plan.png" in controllers and "python -m benchmarks.tree_picture" in controllers
    assert (DOCS / "img" / "tree_plan.png").is_file()


def test_getting_started_has_the_newcomers_path():
    text = (DOCS / "getting-started.md").read_text(encoding="utf-8")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    quickstart = re.search(r"^## Quickstart\n(.*?)(?=^## )", readme, flags=re.M | re.S).group(1)
    for command in re.findall(r"```bash\n(.*?)\n```", quickstart, flags=re.S):
        assert command in text  # the two Quickstart commands, as the README has them
    assert "torch.set_num_threads(1)" in text and "312 s against 29 s" in text
    assert "RawEnvPolicy" in text and "evaluate(" in text


# ----------------------------------------------------------------------------- the tree picture
def test_tree_picture_draws_the_plan(tmp_path):
    from benchmarks.pictures import tree as tree_picture

    out = tree_picture.main(["--out", str(tmp_path / "plan.png"), "--steps", "2"])
    assert out.is_file() and out.stat().st_size > 10_000


def test_tree_picture_checks_its_arguments_first(tmp_path, capsys):
    from benchmarks.pictures import tree as tree_picture

    with pytest.raises(SystemExit) as exc:
        tree_picture.main(["--out", str(tmp_path / "missing" / "plan.png")])
    assert exc.value.code == 2 and "--out" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        tree_picture.main(["--state", "1,x", "--out", str(tmp_path / "plan.png")])
    assert exc.value.code == 2 and "--state" in capsys.readouterr().err
    with pytest.raises(ValueError, match="SDJLS-Nope-v0"):
        tree_picture.main(["--env-id", "SDJLS-Nope-v0", "--out", str(tmp_path / "plan.png")])


# ----------------------------------------------------------------------------- project files
def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def test_license_citation_changelog_and_type_markers():
    config = _pyproject()
    license_text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert config["project"]["license"] == {"text": "MIT"}
    assert license_text.startswith("MIT License")
    assert "Copyright (c) 2026 the sdjls-gym developers" in license_text
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert "## [Unreleased]" in changelog and "Keep a Changelog" in changelog
    package_data = config["tool"]["setuptools"]["package-data"]
    for package in ("sdjls_gym", "controllers", "benchmarks"):
        assert (ROOT / package / "py.typed").is_file(), package
        assert "py.typed" in package_data[package], package


def test_citation_cites_the_software_and_the_paper():
    yaml = pytest.importorskip("yaml")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["version"] == _pyproject()["project"]["version"] and cff["license"] == "MIT"
    paper = cff["preferred-citation"]
    assert paper["type"] == "article" and paper["journal"] == "Systems & Control Letters"
    assert paper["year"] == 2014
    assert [a["family-names"] for a in paper["authors"]] == [
        "Chitraganti", "Aberkane", "Aubrun", "Valencia-Palomo", "Dragan",
    ]  # fmt: skip
    readme = (ROOT / "README.md").read_text(encoding="utf-8").replace("\n> ", "\n")
    readme = " ".join(readme.split())
    assert paper["title"].lower() in readme.lower()  # the title the README cites


def test_built_site_is_ignored_by_git_ruff_and_pytest():
    for path in ("site/index.html", ".ci/site/index.html"):
        out = subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT, check=False)
        assert out.returncode == 0, f"{path} is not ignored by .gitignore"
    config = _pyproject()
    assert "site" in config["tool"]["ruff"]["extend-exclude"]
    assert "site" in config["tool"]["pytest"]["ini_options"]["norecursedirs"]


def test_docs_extra_is_bounded_and_ci_builds_the_site_strictly():
    docs = _pyproject()["project"]["optional-dependencies"]["docs"]
    names = {re.match(r"[\w-]+", r).group(0) for r in docs}
    assert {"mkdocs", "mkdocs-material", "mkdocstrings"} <= names
    assert all("<" in r for r in docs)
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert 'pip install -e ".[docs]"' in ci and "mkdocs build --strict" in ci
    assert ci.index("python -m pytest -q -n 2\n") < ci.index("mkdocs build --strict")
    pre_commit = (ROOT / ".pre-commit-config.yaml").read_text(encoding="utf-8")
    assert "entry: mkdocs build --strict" in pre_commit


# ----------------------------------------------------------------------------- console commands
COMMANDS = {
    "sdjls-reproduce-paper": "reproduce_paper",
    "sdjls-compare-rl": "compare_rl",
    "sdjls-evaluate": "evaluate",
    "sdjls-speed": "speed",
    "sdjls-suite": "suite",
    "sdjls-tune": "tune",
}


def test_console_commands_are_declared():
    scripts = _pyproject()["project"]["scripts"]
    assert {name: target.split(":")[1] for name, target in scripts.items()} == COMMANDS
    for target in scripts.values():
        module, _, attribute = target.partition(":")
        assert callable(getattr(importlib.import_module(module), attribute)), target


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_console_command_help_exits_0(command):
    """What the installed command runs (``sys.exit(function())``), with ``--help``."""
    target = _pyproject()["project"]["scripts"][command]
    module, _, attribute = target.partition(":")
    code = (
        f"import sys; from {module} import {attribute} as f; "
        f"sys.argv = [{command!r}, '--help']; sys.exit(f())"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=False
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "usage:" in run.stdout


def test_console_command_exits_0_when_main_returns_its_result(monkeypatch):
    """``sys.exit(main())`` with a ``main`` that returns a summary would print it and exit 1."""
    from benchmarks import cli, reproduce_paper

    monkeypatch.setattr(reproduce_paper, "main", lambda: {"claims": 6})
    with pytest.raises(SystemExit) as exc:
        sys.exit(reproduce_paper.main())
    assert exc.value.code != 0  # what a console command pointing at main would do
    assert cli.reproduce_paper() == 0


def test_the_hidden_pages_results_are_the_reports_own():
    """``docs/hidden.md``'s results are copied from ``results/hidden/REPORT.md``, where code
    writes them from the numbers: every table row is a row of the report, every bullet one of its
    conclusions (a sentence typed by hand, or left over from an earlier scoring, fails here)."""
    from conftest import section

    page = (DOCS / "hidden.md").read_text(encoding="utf-8")
    report = (ROOT / "results/hidden/REPORT.md").read_text(encoding="utf-8")
    assert not uncopied_rows(page, "Results", ROOT / "results/hidden/REPORT.md", 8)

    def bullets(text: str) -> list[str]:
        return [" ".join(b.split()) for b in re.findall(r"^- (.*?)(?=^- |^$|\Z)", text,
                                                         flags=re.M | re.S)]  # fmt: skip

    shown = bullets(section(page, "Results"))
    stated = bullets(section(report, "Conclusions"))
    assert shown and all(b in stated for b in shown), [b for b in shown if b not in stated]
