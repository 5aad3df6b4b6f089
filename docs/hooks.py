"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks: [docs/hooks.py]``).

* **Figures where the benchmarks write them.** Every PNG of ``results/`` is added to the site
  under the same path, so a page shows ``![...](results/render/macro_rhc.png)`` and the strict
  build checks that the file exists; no copy in ``docs/`` can go stale.
* **Every public name once.** A reference page holds bare ``::: module`` lines. For a module with
  ``__all__``, the names it defines itself are rendered there, and the names it re-exports from
  another documented module (``from sdjls_gym.model import SDJLSModel`` in ``sdjls_gym``) are
  listed in a table that links to where they are rendered, instead of being rendered twice.
  :func:`exports` decides which is which from the source (no import), and ``tests/test_docs.py``
  uses it to check the built site.
* **Sphinx roles.** Docstrings name objects as ``:class:`~sdjls_gym.env.SDJLSEnv```; the page
  shows the name in code, without the role (and without the path after ``~``).
"""

from __future__ import annotations

import ast
import html
import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sdjls_gym", "controllers", "benchmarks")
REFERENCE = ROOT / "docs" / "reference"


# ----------------------------------------------------------------------------- public names
def module_file(module: str) -> Path:
    """The source file of ``module`` (a package's ``__init__.py``)."""
    path = ROOT.joinpath(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


@cache
def all_modules() -> tuple[str, ...]:
    """Every module of the three packages, in file order (a package's ``__main__``, which runs a
    script when imported, is its package's: ``python -m package``)."""
    out = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if path.name == "__main__.py":
                continue
            parts = path.relative_to(ROOT).with_suffix("").parts
            out.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return tuple(out)


@dataclass(frozen=True)
class ModuleNames:
    """What one module's source says about its names.

    Attributes
    ----------
    defined : frozenset of str
        Names bound at the top level by ``def``, ``class`` or an assignment.
    imported : dict
        Name -> (module, name) for every top-level ``from module import name [as alias]``.
    all : tuple of str or None
        ``__all__`` (with its ``+=`` parts), or None when the module has none.
    """

    defined: frozenset[str]
    imported: dict[str, tuple[str, str]]
    all: tuple[str, ...] | None


def _absolute(module: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    parts = module.split(".")
    if module_file(module).name != "__init__.py":
        parts = parts[:-1]
    parts = parts[: len(parts) - node.level + 1]
    return ".".join([*parts, node.module] if node.module else parts)


@cache
def module_names(module: str) -> ModuleNames:
    """Parse ``module``'s source for its top-level names and ``__all__``."""
    tree = ast.parse(module_file(module).read_text(encoding="utf-8"))
    defined: set[str] = set()
    imported: dict[str, tuple[str, str]] = {}
    names: list[str] | None = None
    for node in tree.body:
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                imported[alias.asname or alias.name] = (_absolute(module, node), alias.name)
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            defined.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                if not isinstance(target, ast.Name):
                    continue
                if target.id != "__all__":
                    defined.add(target.id)
                elif node.value is not None:
                    value = list(ast.literal_eval(node.value))
                    names = (names or []) + value if isinstance(node, ast.AugAssign) else value
    return ModuleNames(frozenset(defined), imported, None if names is None else tuple(names))


@cache
def documented_modules() -> dict[str, Path]:
    """Module -> the reference page whose ``::: module`` line documents it."""
    out: dict[str, Path] = {}
    for page in sorted(REFERENCE.glob("*.md")):
        for line in page.read_text(encoding="utf-8").splitlines():
            match = re.fullmatch(r"::: ([\w.]+)\s*", line)
            if match:
                out[match.group(1)] = page
    return out


@cache
def definition(module: str, name: str) -> tuple[str, str]:
    """``(module, name)`` where ``module.name`` is defined, following re-exports."""
    seen = set()
    while (module, name) not in seen:
        seen.add((module, name))
        names = module_names(module)
        if name in names.defined or name not in names.imported:
            return module, name
        source, original = names.imported[name]
        if source.split(".")[0] not in PACKAGES or not module_file(source).exists():
            return module, name
        module, name = source, original
    return module, name


@cache
def rendered_names(module: str) -> tuple[str, ...]:
    """The public names rendered in ``module``'s own block of the reference."""
    names = module_names(module)
    if names.all is None:  # mkdocstrings' "public" filter: defined here, no leading underscore
        return tuple(sorted(n for n in names.defined if not n.startswith("_")))
    return tuple(n for n in names.all if exports(module).get(n) is None)


@cache
def exports(module: str) -> dict[str, str | None]:
    """Each name of ``module.__all__`` -> the identifier it is rendered under elsewhere, or None
    when it is rendered in ``module``'s block (defined there, or its definition is not in the
    reference)."""
    names = module_names(module)
    documented = documented_modules()
    out: dict[str, str | None] = {}
    for name in names.all or ():
        where, original = definition(module, name)
        if where != module and where in documented and original in rendered_names(where):
            out[name] = f"{where}.{original}"
        else:
            out[name] = None
    return out


def reference_anchor(module: str, name: str) -> str:
    """The HTML id under which the reference shows ``module.name`` (``module.__all__``)."""
    return exports(module).get(name) or f"{module}.{name}"


def _summary(identifier: str) -> str:
    module, name = identifier.rsplit(".", 1)
    tree = ast.parse(module_file(module).read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            if node.name == name:
                paragraphs = (ast.get_docstring(node) or "").strip().split("\n\n")
                # the first paragraph that is not a Markdown heading (Gymnasium-style manuals)
                doc = next((p for p in paragraphs if not p.startswith("#")), "").replace("\n", " ")
                # a table cell: HTML, so that a | inside code does not end the cell
                doc = re.sub(r"``?([^`]+)``?", r"<code>\1</code>", html.escape(doc, quote=False))
                return doc.replace("|", "&#124;")
    return ""


# ----------------------------------------------------------------------------- hooks
def on_files(files: Any, config: Any) -> Any:
    """Add ``results/**/*.png`` to the site's files, at ``results/...``."""
    from mkdocs.structure.files import File

    for path in sorted((ROOT / "results").glob("**/*.png")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith("results/tmp"):  # scratch outputs (gitignored)
            continue
        files.append(
            File(
                rel,
                src_dir=str(ROOT),
                dest_dir=config["site_dir"],
                use_directory_urls=config["use_directory_urls"],
            )
        )
    return files


def _module_block(module: str) -> str:
    elsewhere = {n: ident for n, ident in exports(module).items() if ident is not None}
    if not elsewhere:
        return f"::: {module}"
    own = rendered_names(module)
    members = "[" + ", ".join(own) + "]" if own else "false"
    rows = [
        f"| [`{name}`][{ident}] | `{ident.rsplit('.', 1)[0]}` | {_summary(ident)} |"
        for name, ident in elsewhere.items()
    ]
    return "\n".join(
        [
            f"::: {module}",
            "    options:",
            f"      members: {members}",
            "",
            f'<p class="reexports">Also exported by <code>{module}</code>, documented where'
            " they are defined:</p>",
            "",
            "| name | defined in | summary |",
            "|---|---|---|",
            *rows,
        ]
    )


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """Expand the bare ``::: module`` lines of the reference pages (see the module docstring)."""
    if not page.file.src_uri.startswith("reference/"):
        return markdown
    return re.sub(
        r"^::: ([\w.]+)[ \t]*$(?!\n[ \t]+options:)",
        lambda m: _module_block(m.group(1)) if m.group(1) in all_modules() else m.group(0),
        markdown,
        flags=re.M,
    )


_ROLE = re.compile(
    r":(?:py:)?(?:class|func|meth|attr|data|mod|exc|obj|const):<code>(~?)([^<]*)</code>"
)


def on_page_content(html: str, page: Any, config: Any, files: Any) -> str:
    """Drop Sphinx roles in front of code names (``~a.b.C`` shows as ``C``)."""
    return _ROLE.sub(
        lambda m: f"<code>{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}</code>",
        html,
    )
